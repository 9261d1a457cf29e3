/* The path of a program installed beside the running one (`impasto` and `impasto-bench`
 * find each other this way, in the build tree and once installed). */
#pragma once
#include <stddef.h>

/* dirname(/proc/self/exe)/name into buf: 0, or a negative errno. */
int imp_sibling_path(const char *name, char *buf, size_t size);
