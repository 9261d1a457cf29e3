/* impasto's version, for provenance records. */
#pragma once
#define IMPASTO_VERSION_STRING "0.1.0"
const char *imp_version(void);
