/* The impasto client's subcommands: each cli/cmd-<name>.c defines one
 * `const struct imp_command imp_cmd_<name>` and is listed in cli/main.c. */
#pragma once
#include <stdbool.h>

struct imp_command {
        const char *name;             /* "process", "sim", … */
        const char *summary;          /* one line for `impasto --help` */
        int (*run)(int argc, char **argv);   /* argv[0] is the command name; returns exit code */
        bool hugepages;               /* processes captures: malloc in huge pages (hugepages.h) */
};
