/* Error detail helpers: messages name the file and field and keep the code. */
#include <errno.h>
#include "error.h"
#include "test.h"

int main(void) {
        struct imp_error e = {};
        CHECK_ERR(imp_error_set(&e, -EINVAL, "%s:%d: camera.fx: expected > 0", "rig.cfg", 14), -EINVAL);
        CHECK_STR_EQ(e.msg, "rig.cfg:14: camera.fx: expected > 0");
        CHECK_ERR(imp_error_prefix(&e, "capture set %s: ", "s1"), -EINVAL);
        CHECK_STR_EQ(e.msg, "capture set s1: rig.cfg:14: camera.fx: expected > 0");
        CHECK_ERR(imp_error_set(NULL, -ENOENT, "x"), -ENOENT);
        return TEST_DONE();
}
