/* Version string reported in copy.json provenance and by `impasto --version`. */
#include "version.h"
const char *imp_version(void) { return IMPASTO_VERSION_STRING; }
