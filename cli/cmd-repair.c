/* `impasto repair CAPSET [--dry-run] [--json]`: the explicit repair of what a crash can leave
 * in a capture set (a torn last manifest line, a frame stored but not recorded, .tmp files):
 * each item is moved into CAPSET/quarantine/ (never deleted) and listed. Readers (process,
 * calibrate) never change a set; this is the only way besides resuming a session in impastod.
 * Damage that is not a crash's (a bad line in the middle, a listed frame missing) is refused,
 * exit 3, and nothing is moved. */
#include <getopt.h>
#include <stdio.h>
#include <string.h>
#include "captureset.h"
#include "commands.h"
#include "json-util.h"
#include "log.h"

#define USAGE "usage: impasto repair CAPSET [--dry-run] [--json]\n"

static int run(int argc, char **argv) {
        bool dry_run = false, as_json = false;
        static const struct option longopts[] = {
                { "dry-run", no_argument, NULL, 'n' }, { "json", no_argument, NULL, 'j' },
                { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        while ((c = getopt_long(argc, argv, "njh", longopts, NULL)) >= 0)
                switch (c) {
                case 'n': dry_run = true; break;
                case 'j': as_json = true; break;
                case 'h': printf(USAGE); return 0;
                default: return 2;
                }
        if (optind + 1 != argc) {
                fprintf(stderr, USAGE);
                return 2;
        }
        const char *dir = argv[optind];
        struct imp_error err = {};
        _cleanup_json_ json_t *report = NULL;
        int r = imp_captureset_repair(dir, dry_run, &report, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                log_error("%s: nothing was moved", dir);
                return r == -EBUSY || r == -EACCES || r == -EROFS ? 1 : 3;
        }
        if (as_json) {
                _cleanup_json_ json_t *j = json_pack("{s:s, s:b, s:O}", "set", dir, "dry_run", dry_run, "items", report);
                _cleanup_free_ char *s = j ? json_dumps(j, JSON_COMPACT) : NULL;
                printf("%s\n", s ? s : "{}");
                return s ? 0 : 1;
        }
        size_t i;
        json_t *item;
        json_array_foreach(report, i, item) {
                const char *to = json_string_value(json_object_get(item, "moved_to"));
                printf("%s: %s\n  %s %s\n", json_string_value(json_object_get(item, "path")),
                       json_string_value(json_object_get(item, "reason")), to ? "moved to" : "would move to",
                       to ? to : IMP_CAPTURESET_QUARANTINE "/");
        }
        printf("%s: %d item%s %s\n", dir, r, r == 1 ? "" : "s",
               r == 0 ? "to repair: the set is whole" : dry_run ? "to move (dry run: nothing changed)" : "moved");
        return 0;
}

const struct imp_command imp_cmd_repair = {
        .name = "repair",
        .summary = "move what a crash left in a capture set into its quarantine/ (never deletes)",
        .run = run,
};
