/* Strict numbers from the command line. The whole text must be the number (no trailing
 * "mm", no empty string, no leading blank), finite (no "nan", "inf") and within [min, max];
 * otherwise an error naming the option and the text is logged, e.g.
 *   impasto: --pitch: expected a number from 0.001 to 1000, got 'abc'
 * and -EINVAL is returned (callers exit with the usage code). *ret is left untouched then. */
#pragma once

int imp_parse_double(const char *opt, const char *text, double min, double max, double *ret);
int imp_parse_long(const char *opt, const char *text, long min, long max, long *ret);
/* imp_parse_long for an int option */
int imp_parse_int(const char *opt, const char *text, int min, int max, int *ret);
