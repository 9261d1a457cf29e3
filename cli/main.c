/* impasto: the operator's command-line client and the offline tools.
 * Exit codes: 0 success, 1 failure, 2 usage error, 3 bad input (file named in the message). */
#include <stdio.h>
#include <string.h>
#include "commands.h"
#include "exit-codes.h"
#include "help.h"
#include "hugepages.h"
#include "log.h"

/* Subcommands are declared weak so that the client links while a subcommand's module is
 * not built in this configuration (say, without OpenCV); such a command is not offered. */
#define IMP_COMMANDS(X) X(sim) X(process) X(compare) X(render) X(calibrate) X(plan) X(bench) \
        X(status) X(devices) X(scan) X(jobs) X(import) X(compare_normals) X(view) X(export) \
        X(repair) X(queue) X(report) X(mosaic)
#define DECLARE(n) extern const struct imp_command imp_cmd_##n __attribute__((weak));
IMP_COMMANDS(DECLARE)
#define ENTRY(n) &imp_cmd_##n,
static const struct imp_command *const commands[] = { IMP_COMMANDS(ENTRY) };

static void usage(FILE *f) {
        fprintf(f, "usage: impasto COMMAND [ARGS…]\n\ncommands:\n");
        for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
                if (commands[i])
                        fprintf(f, "  %-10s %s\n", commands[i]->name, commands[i]->summary);
        fprintf(f, "\n'impasto help COMMAND' (or impasto COMMAND --help) describes a command; impasto --version\n");
        fprintf(f, "exit codes: 0 ok, 1 failure, 2 usage, 3 bad input, 4 daemon unreachable, 5 permission denied,\n"
                   "            6 result undetermined, 130 detached from a followed scan or job (Ctrl-C)\n");
}

int main(int argc, char **argv) {
        imp_log_set_ident("impasto");
        if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
                usage(argc < 2 ? stderr : stdout);
                return argc < 2 ? IMP_EXIT_USAGE : IMP_EXIT_OK;
        }
        int r = imp_cli_builtin(argc, argv, commands, sizeof commands / sizeof commands[0], usage);
        if (r >= 0)
                return r;
        for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
                if (commands[i] && !strcmp(commands[i]->name, argv[1])) {
                        if (commands[i]->hugepages)
                                imp_hugepages_reexec(argv);
                        return commands[i]->run(argc - 1, argv + 1);
                }
        return imp_cli_unknown_command(argv[1], commands, sizeof commands / sizeof commands[0]);
}
