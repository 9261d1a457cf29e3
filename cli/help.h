/* The client's own commands and messages, apart from its subcommands: `impasto --version`,
 * `impasto help [COMMAND]` (the same text as `impasto COMMAND --help`) and the "did you
 * mean" of a mistyped command or word. */
#pragma once
#include <stddef.h>
#include <stdio.h>
#include "commands.h"

/* `--version` and `help [COMMAND]`: runs it and returns the exit code; -1 when argv[1] is
 * neither. `usage` prints the command list. cmds[i] may be NULL (a command not built). */
int imp_cli_builtin(int argc, char **argv, const struct imp_command *const *cmds, size_t n_cmds,
                    void (*usage)(FILE *f));

/* "impasto: unknown command 'scna'; did you mean 'scan'?" and where the list is; returns
 * the usage exit code. */
int imp_cli_unknown_command(const char *name, const struct imp_command *const *cmds, size_t n_cmds);

/* The name in `names` (n of them, NULL entries skipped) closest to `word` by edit
 * distance, if it is close enough to be a typo (at most 2 edits, fewer than the word has
 * letters); NULL otherwise. For subcommand words: "unknown action 'strt'; did you mean …". */
const char *imp_cli_suggest(const char *word, const char *const *names, size_t n);

/* "impasto CMD: unknown action 'VERB'; did you mean 'V'? (expected one of: a, b, c)" on
 * stderr; returns the usage exit code. For commands with actions (jobs list|show|retry). */
int imp_cli_unknown_action(const char *cmd, const char *verb, const char *const *verbs, size_t n);
