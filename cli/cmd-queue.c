/* `impasto queue`: the scan queue of impastod (queue.* of proto/PROTOCOL.md). Plans queued
 * for the night start one after another, each as its own session, when the rig is free.
 *   queue add PLAN [--name NAME]   queue list   queue move ID POS   queue cancel ID */
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "client.h"
#include "commands.h"
#include "help.h"
#include "log.h"
#include "numparse.h"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto queue add PLAN [--name NAME] [--json] [--socket PATH]\n"
                   "       impasto queue [list] [--json] [--socket PATH]\n"
                   "       impasto queue move ID POSITION [--json] [--socket PATH]\n"
                   "       impasto queue cancel ID [--json] [--socket PATH]\n"
                   "Queued plans start one after another, each as its own session, when no session holds the\n"
                   "rig and none is paused; the queue survives a restart of impastod.\n");
}

static void human_list(const json_t *r) {
        static const struct imp_client_column cols[] = {
                { "POS", "position", 4 }, { "ID", "id", 8 }, { "NAME", "name", 20 }, { "STATE", "state", 8 },
                { "ADDED", "added", 21 }, { "PLAN", "plan", 0 } };
        const json_t *q = json_object_get(r, "queue"), *e;
        imp_client_print_table(q, cols, ARRAY_SIZE(cols), "the scan queue is empty");
        size_t i;
        json_array_foreach(q, i, e)
                if (*imp_client_str(e, "error"))
                        printf("  %s could not start: %s\n", imp_client_str(e, "id"), imp_client_str(e, "error"));
        if (*imp_client_str(r, "waiting_for"))
                printf("waiting: %s\n", imp_client_str(r, "waiting_for"));
}

static void human_added(const json_t *r) {
        printf("queued %s at position %lld: %s\n", imp_client_str(r, "id"), imp_client_int(r, "position"),
               imp_client_str(r, "plan"));
        if (*imp_client_str(r, "waiting_for"))
                printf("waiting: %s\n", imp_client_str(r, "waiting_for"));
}

static void human_cancelled(const json_t *r) {
        printf("%s cancelled (%s)\n", imp_client_str(r, "id"), imp_client_str(r, "plan"));
}

static int bad_args(const char *verb, int n) {
        static const char *const verbs[] = { "add", "list", "move", "cancel" };
        size_t k;
        for (k = 0; k < ARRAY_SIZE(verbs) && strcmp(verb, verbs[k]); k++)
                ;
        if (k == ARRAY_SIZE(verbs))
                return imp_cli_unknown_action("queue", verb, verbs, ARRAY_SIZE(verbs));
        static const char *const want[] = { "one PLAN", "no arguments", "an ID and a POSITION", "one ID" };
        fprintf(stderr, "impasto queue %s: expected %s, got %d words\n", verb, want[k], n - 1);
        fprintf(stderr, "Run 'impasto help queue' for the usage.\n");
        return IMP_EXIT_USAGE;
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *name = NULL;
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' }, { "socket", required_argument, NULL, 'S' },
                { "name", required_argument, NULL, 'N' }, { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'N': name = optarg; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        int n = argc - optind;
        const char *verb = n > 0 ? argv[optind] : "list";
        if (name && strcmp(verb, "add")) {
                log_error("--name goes with queue add");
                return IMP_EXIT_USAGE;
        }
        if (!strcmp(verb, "list") && n <= 1)
                return imp_client_simple(&o, "queue.list", NULL, human_list);
        if (!strcmp(verb, "add") && n == 2) {
                /* the daemon opens the plan itself: an absolute path when we can */
                char abs[PATH_MAX];
                const char *plan = realpath(argv[optind + 1], abs) ? abs : argv[optind + 1];
                json_t *args = json_pack("{s:s}", "plan", plan);
                if (name)
                        json_object_set_new(args, "name", json_string(name));
                return imp_client_simple(&o, "queue.add", args, human_added);
        }
        if (!strcmp(verb, "move") && n == 3) {
                long pos;
                if (imp_parse_long("POSITION", argv[optind + 2], 1, 256, &pos) < 0)
                        return IMP_EXIT_USAGE;
                return imp_client_simple(&o, "queue.move",
                                         json_pack("{s:s, s:I}", "id", argv[optind + 1], "position", (json_int_t) pos),
                                         human_list);
        }
        if (!strcmp(verb, "cancel") && n == 2)
                return imp_client_simple(&o, "queue.cancel", json_pack("{s:s}", "id", argv[optind + 1]),
                                         human_cancelled);
        return bad_args(verb, n);
}

const struct imp_command imp_cmd_queue = {
        .name = "queue",
        .summary = "the scan queue: add plans for the night, list, move, cancel",
        .run = run,
};
