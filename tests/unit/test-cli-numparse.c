/* cli/numparse.c and the typo suggestions of cli/help.c: strict numbers (whole text, finite,
 * in range) with an error naming the option and the text; "did you mean" by edit distance. */
#include <errno.h>
#include <unistd.h>
#include "help.h"
#include "log.h"
#include "numparse.h"
#include "test.h"

/* What f(…) logs on stderr: the call runs with stderr sent to a temporary file. */
static char logged[512];
static int saved_fd = -1;
static FILE *capture;

static void capture_begin(void) {
        fflush(stderr);
        capture = tmpfile();
        saved_fd = dup(STDERR_FILENO);
        if (!capture || saved_fd < 0 || dup2(fileno(capture), STDERR_FILENO) < 0)
                exit(2);
}

static const char *capture_end(void) {
        fflush(stderr);
        dup2(saved_fd, STDERR_FILENO);
        close(saved_fd);
        rewind(capture);
        size_t n = fread(logged, 1, sizeof logged - 1, capture);
        logged[n] = 0;
        fclose(capture);
        return logged;
}

static void test_double(void) {
        double v = 42;
        CHECK_OK(imp_parse_double("--pitch", "0.25", 0.001, 1000, &v));
        CHECK_NEAR(v, 0.25, 0);
        CHECK_OK(imp_parse_double("--pitch", "1e2", 0.001, 1000, &v));
        CHECK_NEAR(v, 100, 0);
        static const char *const bad[] = { "abc", "", " 1", "1mm", "nan", "inf", "1e400", "0", "1001", "0.5x" };
        for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
                v = 42;
                capture_begin();
                int r = imp_parse_double("--pitch", bad[i], 0.001, 1000, &v);
                const char *msg = capture_end();
                CHECK_ERR(r, -EINVAL);
                CHECK_NEAR(v, 42, 0);    /* untouched */
                char want[64];
                snprintf(want, sizeof want, "got '%s'", bad[i]);
                CHECK_STR_CONTAINS(msg, "--pitch: expected a number from 0.001 to 1000");
                CHECK_STR_CONTAINS(msg, want);
        }
        capture_begin();
        int r = imp_parse_double("--size", "-1", 0, INFINITY, &v);
        const char *msg = capture_end();
        CHECK_ERR(r, -EINVAL);
        CHECK_STR_CONTAINS(msg, "--size: expected a number >= 0, got '-1'");
}

static void test_long(void) {
        long v = 7;
        int i = 7;
        CHECK_OK(imp_parse_long("--limit", "1000", 1, 1000, &v));
        CHECK_INT_EQ(v, 1000);
        CHECK_OK(imp_parse_int("--cell", "-3", -5, 5, &i));
        CHECK_INT_EQ(i, -3);
        static const char *const bad[] = { "abc", "", "1.5", "12x", "0", "1001", "99999999999999999999999" };
        for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++) {
                v = 7;
                capture_begin();
                int r = imp_parse_long("--limit", bad[k], 1, 1000, &v);
                const char *msg = capture_end();
                CHECK_ERR(r, -EINVAL);
                CHECK_INT_EQ(v, 7);
                CHECK_STR_CONTAINS(msg, "--limit: expected an integer from 1 to 1000");
        }
}

static void test_suggest(void) {
        static const char *const cmds[] = { "sim", "process", "compare", "render", NULL, "scan", "status", "jobs" };
        size_t n = sizeof cmds / sizeof cmds[0];
        CHECK_STR_EQ(imp_cli_suggest("scna", cmds, n), "scan");
        CHECK_STR_EQ(imp_cli_suggest("staus", cmds, n), "status");
        CHECK_STR_EQ(imp_cli_suggest("proces", cmds, n), "process");
        CHECK_STR_EQ(imp_cli_suggest("job", cmds, n), "jobs");
        CHECK(imp_cli_suggest("frobnicate", cmds, n) == NULL);
        CHECK(imp_cli_suggest("x", cmds, n) == NULL);     /* one letter is no typo of "sim" */
}

int main(void) {
        imp_log_set_ident("test");
        test_double();
        test_long();
        test_suggest();
        return TEST_DONE();
}
