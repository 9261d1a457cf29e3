/* The viewer's web page (cli/view/), embedded at build time by cli/view/embed.cmake. */
#pragma once
#include <stddef.h>

struct imp_view_asset {
        const char *path;             /* "/index.html" */
        const char *mime;
        const unsigned char *data;    /* NUL-terminated beyond size */
        size_t size;
};
extern const struct imp_view_asset imp_view_assets[];   /* ends with path NULL */
