/* impastod end to end on the emulated rig: status, devices, plan.validate/estimate (with the
 * file:line of a bad plan), a dome sweep session with a pause and resume, events to done,
 * the capture set checked frame by frame against the plan and the emulator's pixels, the
 * job hand-off to impasto-worker (the harness rig has no projector: the sweep's job fails at
 * once with the worker's error kept, and is retried by hand; a processable set queued into
 * STATE/jobs is picked up, reports its stages as `job` events and ends done with the
 * --worker-args honoured), bounded retries of a worker that never claims its job, the disk
 * space check, and SIGTERM leaving the lights off and exiting 0. */
#include "test-daemon-harness.c"

#define PORT 15851
#define N_LIGHTS 4
#define WORKER IMPASTO_BINARY_DIR "/cli/impasto-worker"
#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"

static json_t *job_file(const struct harness *h, const char *id) {
        char p[1024];
        snprintf(p, sizeof p, "%s/jobs/%s.json", h->state, id);
        struct imp_error e = { 0 };
        json_t *j = NULL;
        if (imp_json_load(p, &j, &e) < 0)
                CHECK_MSG(0, "%s", e.msg);
        return j;
}

/* A job written into the queue by another tool: the daemon picks it up (inotify). */
static void queue_job(const struct harness *h, const char *id, const char *capture, const char *copy) {
        char p[1024], tmp[1100], text[4096];
        snprintf(p, sizeof p, "%s/jobs/%s.json", h->state, id);
        snprintf(tmp, sizeof tmp, "%s.tmp", p);
        snprintf(text, sizeof text, "{\"id\":\"%s\",\"capture\":\"%s\",\"copy\":\"%s\",\"state\":\"queued\","
                 "\"attempts\":0,\"max_attempts\":2,\"error\":null,\"session\":\"%s\",\"queued\":\"2025-01-01T00:00:00Z\","
                 "\"worker_args\":\"--holdout 2\"}\n", id, capture, copy, id);
        h_write(tmp, text);
        CHECK_MSG(rename(tmp, p) == 0, "rename %s: %s", p, strerror(errno));
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        char plan[512], bad[512], tiny[512];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        snprintf(bad, sizeof bad, "%s/bad.cfg", h.dir);
        snprintf(tiny, sizeof tiny, "%s/tiny.cfg", h.dir);
        h_write(plan, "# a dome sweep\ndome = { lights = \"all\"; exposures_us = [1000.0, 2000.0]; };\n"
                      "dark = { count = 1; };\n");
        h_write(bad, "dome = {\n  lights = [0, 1];\n  exposures_us = [-5.0];\n};\n");
        h_write(tiny, "dome = { lights = [1]; exposures_us = [1000.0]; };\n");
        const size_t frames = N_LIGHTS * 2 + 2;

        struct stat wst;
        if (stat(WORKER, &wst) < 0 || stat(IMPASTO, &wst) < 0)
                TEST_SKIP("%s or %s not built", WORKER, IMPASTO);
        h_start(&h, (const char *const[]) { "--worker-cmd", WORKER, "--worker-args", "--holdout 2",
                                            "--min-free-bytes", "0", NULL });
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        CHECK_INT_EQ(c.role, IMP_PROTO_ROLE_OPERATOR);

        json_t *r = tc_ok(&c, "status", NULL);
        CHECK(r && json_is_true(json_object_get(json_object_get(r, "rig"), "calibrated")));
        CHECK(r && json_is_null(json_object_get(r, "session")));
        json_decref(r);
        r = tc_ok(&c, "devices", NULL);
        json_t *devs = json_object_get(r, "devices");
        CHECK_INT_EQ(json_array_size(devs), 2);
        size_t i;
        json_t *dv;
        json_array_foreach(devs, i, dv) {
                CHECK_STR_EQ(json_string_value(json_object_get(dv, "state")), "ok");
        }
        json_decref(r);
        r = tc_ok(&c, "rig", NULL);
        CHECK_STR_EQ(json_string_value(json_object_get(r, "name")), "test-rig");
        json_decref(r);

        r = tc_ok(&c, "plan.validate", h_arg("plan", plan));
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), frames);
        json_decref(r);
        r = tc_ok(&c, "plan.estimate", h_arg("plan", plan));
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), frames);
        CHECK_INT_GE(json_integer_value(json_object_get(r, "bytes")), frames * H_WIDTH * H_HEIGHT * 2);
        CHECK(json_real_value(json_object_get(r, "duration_s")) > 0);
        CHECK(json_object_get(r, "disk_needed") != NULL);
        json_decref(r);
        char msg[1024];
        CHECK_INT_EQ(tc_err(&c, "plan.validate", h_arg("plan", bad), msg, sizeof msg), IMP_PROTO_E_INVALID_PLAN);
        CHECK_STR_CONTAINS(msg, "bad.cfg:");
        CHECK_STR_CONTAINS(msg, "exposures_us");
        CHECK_INT_EQ(tc_err(&c, "plan.estimate", h_arg("plan", "/nonexistent/plan.cfg"), NULL, 0),
                     IMP_PROTO_E_NOT_FOUND);
        CHECK_INT_EQ(tc_err(&c, "session.show", h_arg("session", "nope"), NULL, 0), IMP_PROTO_E_NOT_FOUND);

        /* The session, paused once on the way. */
        r = tc_ok(&c, "session.start", json_pack("{s:s, s:s}", "plan", plan, "name", "sweep"));
        char id[128] = "";
        snprintf(id, sizeof id, "%s", r ? json_string_value(json_object_get(r, "session")) : "");
        json_decref(r);
        CHECK_INT_EQ(tc_err(&c, "session.start", h_arg("plan", plan), NULL, 0), IMP_PROTO_E_BUSY);
        enum imp_proto_errcode pe = tc_err(&c, "session.pause", h_arg("session", id), NULL, 0);
        if (pe == IMP_PROTO_E_NONE) {
                r = tc_ok(&c, "session.show", h_arg("session", id));
                CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
                json_decref(r);
                CHECK_INT_EQ(imp_emu_rig_lit_light(h.rig), -1);        /* paused: lights off */
                CHECK_INT_EQ(tc_err(&c, "session.pause", h_arg("session", id), NULL, 0), IMP_PROTO_E_BAD_STATE);
                json_decref(tc_ok(&c, "session.resume", h_arg("session", id)));
        } else
                CHECK_MSG(pe == IMP_PROTO_E_BAD_STATE, "pause: %s", imp_proto_error_code_name(pe));
        CHECK_OK(tc_wait_done(&c, 1, 30000));
        CHECK_STR_EQ(c.done_state, "completed");
        CHECK_INT_EQ(c.n_frames, frames);
        CHECK(!c.seq_gap);
        /* Without a projector there is no geometry: the worker fails the job at its first
         * attempt (a permanent error) and its message is kept. */
        CHECK_OK(tc_wait_job(&c, "failed", 20000));

        r = tc_ok(&c, "session.show", h_arg("session", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "completed");
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), frames);
        char setdir[1024];
        snprintf(setdir, sizeof setdir, "%s", json_string_value(json_object_get(r, "path")));
        json_decref(r);
        r = tc_ok(&c, "session.list", NULL);
        CHECK_INT_EQ(json_array_size(json_object_get(r, "sessions")), 1);
        json_decref(r);
        r = tc_ok(&c, "jobs.show", h_arg("job", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "failed");
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "attempts")), 1);
        CHECK_STR_CONTAINS(json_string_value(json_object_get(json_object_get(r, "error"), "message")),
                           "no projector");
        json_decref(r);
        json_t *jf = job_file(&h, id);          /* the one format: what impasto-worker wrote */
        CHECK_STR_EQ(json_string_value(json_object_get(jf, "state")), "failed");
        CHECK_STR_EQ(json_string_value(json_object_get(jf, "capture")), setdir);
        CHECK_STR_EQ(json_string_value(json_object_get(jf, "session")), id);
        CHECK_STR_EQ(json_string_value(json_object_get(jf, "worker_args")), "--holdout 2");
        CHECK_STR_CONTAINS(json_string_value(json_object_get(jf, "error")), "no projector");
        json_decref(jf);
        /* retried by hand: queued with attempts reset, the old error kept until it runs */
        r = tc_ok(&c, "jobs.retry", h_arg("job", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "queued");
        json_decref(r);
        snprintf(c.job_state, sizeof c.job_state, "queued");
        CHECK_OK(tc_wait_job(&c, "failed", 20000));
        r = tc_ok(&c, "jobs.show", h_arg("job", id));
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "attempts")), 1);
        json_decref(r);
        CHECK_INT_EQ(tc_err(&c, "session.resume", h_arg("session", id), NULL, 0), IMP_PROTO_E_BAD_STATE);

        /* A processable capture set queued by another tool: stages as job events, then done. */
        char cmd[2048], tinyset[600], tinycopy[600];
        snprintf(tinyset, sizeof tinyset, "%s/tiny-capture", h.dir);
        snprintf(tinycopy, sizeof tinycopy, "%s/tiny-copy", h.dir);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s/tests/data/worker-tiny.cfg --plan "
                 "%s/tests/data/worker-tiny-plan.cfg --out %s --quiet --threads 2 >/dev/null", IMPASTO,
                 IMPASTO_SOURCE_DIR, IMPASTO_SOURCE_DIR, tinyset);
        CHECK_INT_EQ(system(cmd), 0);
        unsigned progress_before = c.n_job_progress;
        queue_job(&h, "tiny-external", tinyset, tinycopy);
        CHECK_OK(tc_wait_job(&c, "done", 60000));
        CHECK_MSG(c.n_job_progress > progress_before, "no job event named a stage (%u)", c.n_job_progress);
        CHECK_MSG(c.job_progress > 0 && c.job_progress <= 1, "stage progress %g", c.job_progress);
        r = tc_ok(&c, "jobs.show", h_arg("job", "tiny-external"));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "done");
        CHECK_STR_EQ(json_string_value(json_object_get(r, "output")), tinycopy);
        CHECK_NEAR(json_number_value(json_object_get(r, "progress")), 1.0, 1e-9);
        json_decref(r);
        CHECK_INT_EQ(tc_err(&c, "jobs.retry", h_arg("job", "tiny-external"), NULL, 0), IMP_PROTO_E_BAD_STATE);
        char copyjson[700];
        snprintf(copyjson, sizeof copyjson, "%s/copy.json", tinycopy);
        json_t *cj = NULL;
        struct imp_error ce = { 0 };
        CHECK_MSG(imp_json_load(copyjson, &cj, &ce) == 0, "%s", ce.msg);
        /* --worker-args "--holdout 2" reached the worker: light 2 of [0, 2] re-rendered */
        json_t *val = json_object_get(json_object_get(json_object_get(cj, "stages"), "btf"), "validation");
        CHECK_INT_EQ(json_integer_value(json_object_get(val, "lights")), 1);
        json_decref(cj);
        CHECK_INT_EQ(h_verify_set(setdir, plan, true), frames);
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(h.rig), 1);
        CHECK_INT_EQ(imp_emu_rig_lit_light(h.rig), -1);

        /* SIGTERM with a session running: exit 0, lights off, the session resumable. */
        r = tc_ok(&c, "session.start", json_pack("{s:s, s:s}", "plan", plan, "name", "term"));
        char id2[128] = "";
        snprintf(id2, sizeof id2, "%s", r ? json_string_value(json_object_get(r, "session")) : "");
        json_decref(r);
        tc_close(&c);
        usleep(30000);
        h_kill(&h, SIGTERM);
        int st = h_wait(&h, 10000);
        CHECK_MSG(st >= 0 && WIFEXITED(st) && WEXITSTATUS(st) == 0, "impastod after SIGTERM: status %d", st);
        CHECK_INT_EQ(imp_emu_rig_lit_light(h.rig), -1);

        /* Restart with a worker that fails and no disk to spare. */
        h_start(&h, (const char *const[]) { "--worker-cmd", "/bin/false", "--job-attempts", "2",
                                            "--min-free-bytes", "1000000000000000", NULL });
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        r = tc_ok(&c, "session.show", h_arg("session", id2));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
        CHECK(json_is_true(json_object_get(r, "interrupted")));
        json_decref(r);
        CHECK_INT_EQ(tc_err(&c, "session.start", h_arg("plan", tiny), msg, sizeof msg), IMP_PROTO_E_IO);
        CHECK_STR_CONTAINS(msg, "disk space");
        CHECK_INT_EQ(tc_err(&c, "session.resume", h_arg("session", id2), msg, sizeof msg), IMP_PROTO_E_IO);
        json_decref(tc_ok(&c, "session.abort", h_arg("session", id2)));
        r = tc_ok(&c, "session.show", h_arg("session", id2));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "aborted");
        json_decref(r);
        /* The jobs survived the restart as they were. */
        r = tc_ok(&c, "jobs.show", h_arg("job", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "failed");
        CHECK_STR_CONTAINS(json_string_value(json_object_get(json_object_get(r, "error"), "message")),
                           "no projector");
        json_decref(r);
        r = tc_ok(&c, "jobs.show", h_arg("job", "tiny-external"));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "done");
        json_decref(r);
        tc_close(&c);
        h_kill(&h, SIGTERM);
        CHECK(h_wait(&h, 10000) == 0);

        /* A worker that dies without touching its job: its last words reach the job's error,
         * all it printed is in the job's log. */
        char dying[512];
        snprintf(dying, sizeof dying, "%s/dying-worker.sh", h.dir);
        h_write(dying, "#!/bin/sh\necho \"opening $1 with OMP_WAIT_POLICY=${OMP_WAIT_POLICY-unset}\"\n"
                       "echo 'worker: out of luck on this tile' >&2\nexit 1\n");
        unsetenv("OMP_WAIT_POLICY");            /* the daemon's: its workers get passive */
        CHECK_MSG(chmod(dying, 0755) == 0, "chmod %s: %s", dying, strerror(errno));
        h_start(&h, (const char *const[]) { "--worker-cmd", dying, "--job-attempts", "2",
                                            "--min-free-bytes", "0", NULL });
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        r = tc_ok(&c, "session.start", json_pack("{s:s, s:s}", "plan", tiny, "name", "tiny"));
        char id3[128] = "";
        snprintf(id3, sizeof id3, "%s", r ? json_string_value(json_object_get(r, "session")) : "");
        json_decref(r);
        CHECK_OK(tc_wait_done(&c, 1, 20000));
        CHECK_OK(tc_wait_job(&c, "failed", 20000));
        r = tc_ok(&c, "jobs.show", h_arg("job", id3));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "failed");
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "attempts")), 2);
        const char *msg3 = json_string_value(json_object_get(json_object_get(r, "error"), "message"));
        CHECK_STR_CONTAINS(msg3, "exit status 1");
        CHECK_STR_CONTAINS(msg3, "its last output: \"worker: out of luck on this tile\"");
        const char *logp = json_string_value(json_object_get(r, "log"));
        CHECK_MSG(logp != NULL, "jobs.show names no log");
        if (logp) {
                char *text = NULL;
                size_t len = 0;
                FILE *lf = fopen(logp, "r");
                CHECK_MSG(lf != NULL, "%s: %s", logp, strerror(errno));
                if (lf) {
                        text = calloc(1, 8192);
                        len = text ? fread(text, 1, 8191, lf) : 0;
                        fclose(lf);
                }
                /* both attempts, standard output and error */
                CHECK_MSG(len > 0 && strstr(text, "attempt 1") && strstr(text, "attempt 2") && strstr(text, "opening /"),
                          "the job's log: %s", text ? text : "(unread)");
                CHECK_MSG(len > 0 && strstr(text, "with OMP_WAIT_POLICY=passive\n"), "the job's log: %s",
                          text ? text : "(unread)");
                free(text);
        }
        json_decref(r);
        r = tc_ok(&c, "jobs.retry", h_arg("job", id3));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "queued");
        json_decref(r);
        r = tc_ok(&c, "jobs.list", NULL);
        CHECK_INT_EQ(json_array_size(json_object_get(r, "jobs")), 3);
        json_decref(r);
        tc_close(&c);
        h_kill(&h, SIGTERM);
        CHECK(h_wait(&h, 10000) == 0);
out:
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        h_teardown(&h);
        return TEST_DONE();
}
