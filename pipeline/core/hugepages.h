/* Transparent huge pages for malloc in the processing programs (docs/processing-speed.md). */
#pragma once

/* glibc (≥ 2.35) advises malloc's mmap'd chunks and its heap for transparent huge pages
 * when GLIBC_TUNABLES holds glibc.malloc.hugetlb=1, and reads that variable only when the
 * program starts. Call first thing in main() of a program that processes captures: unless
 * GLIBC_TUNABLES already names glibc.malloc.hugetlb (a run or a lab that set it, to 1 or to
 * 0, is left as it is), it appends glibc.malloc.hugetlb=1 and execs the program's own file
 * (/proc/self/exe resolved) with the same argv; the pid, name, open files and arguments stay. Returns only when nothing was done or
 * the exec failed (the program then runs as before). A no-op in sanitizer builds, whose
 * allocator ignores the tunable. */
void imp_hugepages_reexec(char **argv);
