/* Assertion macros for impasto tests: each prints the expression and both values; the
 * test's exit code counts failures. Exit 77 means skipped (CTest SKIP_RETURN_CODE). */
#pragma once
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>

static int test_failures_ __attribute__((unused));
static int test_checks_ __attribute__((unused));

#define TEST_FAIL_(...) do { test_failures_++; fprintf(stderr, "%s:%d: FAIL: ", __FILE__, __LINE__); \
        fprintf(stderr, __VA_ARGS__); fputc('\n', stderr); } while (0)

#define CHECK(cond) do { test_checks_++; if (!(cond)) TEST_FAIL_("%s", #cond); } while (0)
#define CHECK_MSG(cond, ...) do { test_checks_++; if (!(cond)) TEST_FAIL_(__VA_ARGS__); } while (0)
#define CHECK_INT_EQ(a, b) do { long long a_ = (long long)(a), b_ = (long long)(b); test_checks_++; \
        if (a_ != b_) TEST_FAIL_("%s == %s: %lld != %lld", #a, #b, a_, b_); } while (0)
#define CHECK_INT_GE(a, b) do { long long a_ = (long long)(a), b_ = (long long)(b); test_checks_++; \
        if (!(a_ >= b_)) TEST_FAIL_("%s >= %s: %lld < %lld", #a, #b, a_, b_); } while (0)
#define CHECK_OK(r) do { long long r_ = (long long)(r); test_checks_++; \
        if (r_ < 0) TEST_FAIL_("%s: returned %lld (%s)", #r, r_, strerror((int)-r_)); } while (0)
#define CHECK_ERR(r, e) do { long long r_ = (long long)(r); test_checks_++; \
        if (r_ != (e)) TEST_FAIL_("%s: returned %lld, expected %s (%d)", #r, r_, #e, (int)(e)); } while (0)
#define CHECK_NEAR(a, b, tol) do { double a_ = (a), b_ = (b), t_ = (tol); test_checks_++; \
        if (!(fabs(a_ - b_) <= t_)) TEST_FAIL_("%s ≈ %s: %.9g vs %.9g (|diff| %.3g > tol %.3g)", \
                #a, #b, a_, b_, fabs(a_ - b_), t_); } while (0)
#define CHECK_LE(a, b) do { double a_ = (a), b_ = (b); test_checks_++; \
        if (!(a_ <= b_)) TEST_FAIL_("%s <= %s: %.9g > %.9g", #a, #b, a_, b_); } while (0)
#define CHECK_GE(a, b) do { double a_ = (a), b_ = (b); test_checks_++; \
        if (!(a_ >= b_)) TEST_FAIL_("%s >= %s: %.9g < %.9g", #a, #b, a_, b_); } while (0)
#define CHECK_STR_EQ(a, b) do { const char *a_ = (a), *b_ = (b); test_checks_++; \
        if (!a_ || !b_ || strcmp(a_, b_)) TEST_FAIL_("%s == %s: \"%s\" != \"%s\"", #a, #b, \
                a_ ? a_ : "(null)", b_ ? b_ : "(null)"); } while (0)
#define CHECK_STR_CONTAINS(hay, needle) do { const char *h_ = (hay), *n_ = (needle); test_checks_++; \
        if (!h_ || !strstr(h_, n_)) TEST_FAIL_("%s contains \"%s\": got \"%s\"", #hay, n_, \
                h_ ? h_ : "(null)"); } while (0)
#define CHECK_FINITE(x) do { double x_ = (x); test_checks_++; \
        if (!isfinite(x_)) TEST_FAIL_("%s is finite: got %g", #x, x_); } while (0)

/* Ends main(): prints a summary, returns the exit code. */
#define TEST_DONE() ({ fprintf(stderr, "%s: %d checks, %d failed\n", __FILE__, test_checks_, \
        test_failures_); test_failures_ ? 1 : 0; })
#define TEST_SKIP(...) do { fprintf(stderr, "SKIP: "); fprintf(stderr, __VA_ARGS__); \
        fputc('\n', stderr); exit(77); } while (0)

/* The factor on deadlines a test keeps itself: IMPASTO_TIMEOUT_SCALE from ctest (5 under
 * sanitizers, tests/CMakeLists.txt), 1 when unset. */
static inline double test_timeout_scale(void) {
        const char *s = getenv("IMPASTO_TIMEOUT_SCALE");
        double v = s ? atof(s) : 1.0;
        return v >= 1.0 && v <= 100.0 ? v : 1.0;
}

/* A fresh temporary directory for a test's files (mkdtemp under $TMPDIR or /tmp). */
static inline const char *test_tmpdir(void) {
        static char buf[256];
        if (!buf[0]) {
                const char *t = getenv("TMPDIR");
                snprintf(buf, sizeof buf, "%s/impasto-test-XXXXXX", t ? t : "/tmp");
                if (!mkdtemp(buf)) { perror("mkdtemp"); exit(2); }
        }
        return buf;
}

/* Seeded xorshift64 for synthetic test data: uniform in (0, 1) and standard normal. */
static inline double test_urand(uint64_t *s) {
        *s ^= *s << 13; *s ^= *s >> 7; *s ^= *s << 17;
        return ((*s >> 11) + 0.5) / 9007199254740992.0;
}
static inline double test_nrand(uint64_t *s) {
        double u = test_urand(s), v = test_urand(s);
        return sqrt(-2 * log(u)) * cos(2 * M_PI * v);
}

/* Formats a shell command, echoes it and runs it: its exit code, -1 if it did not exit. */
static int test_sh(const char *fmt, ...) __attribute__((format(printf, 1, 2), unused));
static int test_sh(const char *fmt, ...) {
        char cmd[8192];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(cmd, sizeof cmd, fmt, ap);
        va_end(ap);
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}
