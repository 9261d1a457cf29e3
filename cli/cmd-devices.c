/* `impasto devices [--json] [--socket PATH]`: every device of the rig config with its
 * backend and state (the `devices` command of proto/PROTOCOL.md). */
#include <getopt.h>
#include <stdio.h>
#include "client.h"
#include "commands.h"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto devices [--json] [--socket PATH]\n");
}

static void human(const json_t *r) {
        const json_t *list = json_object_get(r, "devices"), *d;
        size_t i;
        if (!json_array_size(list)) {
                printf("no devices configured\n");
                return;
        }
        printf("%-12s %-10s %-10s %-7s %s\n", "NAME", "CLASS", "BACKEND", "STATE", "DETAIL");
        json_array_foreach(list, i, d)
                printf("%-12s %-10s %-10s %-7s %s\n", imp_client_str(d, "name"), imp_client_str(d, "class"),
                       imp_client_str(d, "backend"), imp_client_str(d, "state"), imp_client_str(d, "detail"));
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' }, { "socket", required_argument, NULL, 'S' },
                { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        if (optind != argc) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        return imp_client_simple(&o, "devices", NULL, human);
}

const struct imp_command imp_cmd_devices = {
        .name = "devices",
        .summary = "the rig's cameras, projector, dome and trigger with their state",
        .run = run,
};
