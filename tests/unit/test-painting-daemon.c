/* impastod and painting plans until tile sessions are wired in (docs/painting.md): a plan
 * with a painting group validates and estimates like any plan, but session.start refuses it
 * with a message naming the plan and why, instead of capturing one tile's frames as if they
 * were the painting. Modbus port 15931; run in a private network namespace. */
#define _GNU_SOURCE 1
#include "test-daemon-harness.c"

#define PORT 15931
#define N_LIGHTS 4

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        char plan[512], msg[1024] = "";
        snprintf(plan, sizeof plan, "%s/painting.cfg", h.dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [1000.0]; };\n"
                      "painting = { extent_mm = [100.0, 54.0]; fov_mm = [40.0, 30.0]; };\n");
        h_start(&h, (const char *const[]) { "--min-free-bytes", "0", NULL });
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        json_t *r = tc_ok(&c, "plan.validate", h_arg("plan", plan));
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), N_LIGHTS);
        json_decref(r);
        CHECK_INT_EQ(tc_err(&c, "session.start", h_arg("plan", plan), msg, sizeof msg), IMP_PROTO_E_INVALID_PLAN);
        CHECK_STR_CONTAINS(msg, "painting.cfg: a plan with a painting group");
        r = tc_ok(&c, "status", NULL);
        CHECK(r && json_is_null(json_object_get(r, "session")));
        json_decref(r);
        tc_close(&c);
out:
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        h_teardown(&h);
        return TEST_DONE();
}
