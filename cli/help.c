/* impasto --version, impasto help [COMMAND], and "did you mean" for typos (cli/help.h). */
#include <string.h>
#include "conf.h"
#include "help.h"
#include "log.h"
#include "macro.h"
#include "version.h"

#define EXIT_USAGE 2    /* cli/main.c: 2 usage error */
#define MAX_TYPO 2

const char *imp_cli_suggest(const char *word, const char *const *names, size_t n) {
        const char *best = NULL;
        int best_d = MAX_TYPO + 1;
        int len = (int) strlen(word);
        for (size_t i = 0; i < n; i++) {
                if (!names[i])
                        continue;
                int d = imp_edit_distance(word, names[i]);
                if (d < best_d && d < len) {
                        best_d = d;
                        best = names[i];
                }
        }
        return best;
}

static const struct imp_command *find(const char *name, const struct imp_command *const *cmds, size_t n) {
        for (size_t i = 0; i < n; i++)
                if (cmds[i] && !strcmp(cmds[i]->name, name))
                        return cmds[i];
        return NULL;
}

int imp_cli_unknown_command(const char *name, const struct imp_command *const *cmds, size_t n_cmds) {
        const char *names[64];
        size_t n = 0;
        for (size_t i = 0; i < n_cmds && n < ARRAY_SIZE(names); i++)
                names[n++] = cmds[i] ? cmds[i]->name : NULL;
        const char *s = imp_cli_suggest(name, names, n);
        if (s)
                fprintf(stderr, "impasto: unknown command '%s'; did you mean '%s'?\n", name, s);
        else
                fprintf(stderr, "impasto: unknown command '%s'\n", name);
        fprintf(stderr, "Run 'impasto help' for the list of commands.\n");
        return EXIT_USAGE;
}

int imp_cli_builtin(int argc, char **argv, const struct imp_command *const *cmds, size_t n_cmds,
                    void (*usage)(FILE *f)) {
        if (!strcmp(argv[1], "--version")) {
                printf("impasto %s\n", imp_version());
                return 0;
        }
        if (strcmp(argv[1], "help"))
                return -1;
        if (argc == 2) {
                usage(stdout);
                return 0;
        }
        if (argc > 3) {
                fprintf(stderr, "impasto help: expected one command, got %d words (usage: impasto help [COMMAND])\n",
                        argc - 2);
                return EXIT_USAGE;
        }
        const struct imp_command *c = find(argv[2], cmds, n_cmds);
        if (!c)
                return imp_cli_unknown_command(argv[2], cmds, n_cmds);
        char *args[] = { (char *) c->name, (char *) "--help", NULL };
        return c->run(2, args);
}

int imp_cli_unknown_action(const char *cmd, const char *verb, const char *const *verbs, size_t n) {
        char list[256] = "";
        for (size_t i = 0; i < n; i++) {
                size_t len = strlen(list);
                snprintf(list + len, sizeof list - len, "%s%s", i ? ", " : "", verbs[i]);
        }
        const char *s = imp_cli_suggest(verb, verbs, n);
        if (s)
                fprintf(stderr, "impasto %s: unknown action '%s'; did you mean '%s'? (expected one of: %s)\n", cmd,
                        verb, s, list);
        else
                fprintf(stderr, "impasto %s: unknown action '%s' (expected one of: %s)\n", cmd, verb, list);
        return EXIT_USAGE;
}
