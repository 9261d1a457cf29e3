/* `impasto bench hard` (bench/hard.c): the hard-case suite and docs/hard-cases.md. */
#pragma once

int imp_bench_hard(int argc, char **argv);
