/* The exit codes of impasto's programs (`impasto --help` lists them). The
 * daemon's calibration routines pass them through, so they are one list for every layer. */
#pragma once

#define IMP_EXIT_OK 0
#define IMP_EXIT_FAILURE 1            /* failed (out of memory, I/O, a fit that did not run) */
#define IMP_EXIT_USAGE 2              /* bad command line */
#define IMP_EXIT_BADINPUT 3           /* bad input files: a set missing what it needs, malformed */
#define IMP_EXIT_UNREACHABLE 4        /* the daemon (or the job queue) cannot be reached */
#define IMP_EXIT_PERMISSION 5         /* permission denied */
#define IMP_EXIT_UNDETERMINED 6       /* done, but a result is not determined (flagged) */
#define IMP_EXIT_SKIP 77              /* a bench or test whose hardware is absent */
