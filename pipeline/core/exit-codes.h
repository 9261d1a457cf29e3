/* The exit codes of impasto's programs (`impasto --help` lists them). One list for every
 * layer: the client maps daemon errors onto them (proto/), the daemon's calibration
 * routines pass them through, the offline commands return them. */
#pragma once

enum imp_exit {
        IMP_EXIT_OK = 0,
        IMP_EXIT_FAILURE = 1,         /* failed (out of memory, I/O, a fit that did not run) */
        IMP_EXIT_USAGE = 2,           /* bad command line */
        IMP_EXIT_BAD_INPUT = 3,       /* bad input files: a set missing what it needs, malformed */
        IMP_EXIT_UNREACHABLE = 4,     /* the daemon cannot be reached */
        IMP_EXIT_PERMISSION = 5,      /* permission denied */
        IMP_EXIT_UNDETERMINED = 6,    /* done, but a result is not determined (flagged) */
        IMP_EXIT_SKIP = 77,           /* a bench or test whose hardware is absent */
};
