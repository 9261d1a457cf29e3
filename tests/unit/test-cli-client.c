/* The `impasto` daemon commands against a scripted stand-in for impastod on a UNIX socket
 * (the real daemon gets its own client tests): human and --json output, error codes mapped
 * to exit codes (3 bad input, 5 permission denied, 1 unknown command or protocol version),
 * a daemon that closes before replying or does not exist (4), and `scan start --follow`
 * drawing progress from events, counting a seq gap as dropped. */
#include <signal.h>
#include <stdio.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"

static int run(const char *cmd, char **ret_out) {
        char full[4096];
        snprintf(full, sizeof full, "%s 2>&1", cmd);
        fprintf(stderr, "$ %s\n", cmd);
        FILE *p = popen(full, "r");
        if (!p)
                return -1;
        char *buf = calloc(1, 65536);
        size_t n = buf ? fread(buf, 1, 65535, p) : 0;
        int st = pclose(p);
        fprintf(stderr, "%.*s", (int) n, buf ? buf : "");
        *ret_out = buf;
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static int listen_at(const char *path, bool do_listen) {
        struct sockaddr_un sa = { .sun_family = AF_UNIX };
        snprintf(sa.sun_path, sizeof sa.sun_path, "%s", path);
        int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (fd < 0 || bind(fd, (struct sockaddr *) &sa, sizeof sa) < 0 || (do_listen && listen(fd, 8) < 0)) {
                perror(path);
                exit(2);
        }
        return fd;
}

static void say(int fd, const char *fmt, ...) _printf_(2, 3);
static void say(int fd, const char *fmt, ...) {
        char buf[4096];
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(buf, sizeof buf - 1, fmt, ap);
        va_end(ap);
        buf[n++] = '\n';
        if (write(fd, buf, (size_t) n) != n)
                _exit(3);
}

/* One connection of the stand-in: answers by command until the client closes. */
static void serve_one(int fd, int protocol) {
        say(fd, "{\"impasto\":\"0.1.0\",\"protocol\":%d,\"role\":\"observer\"}", protocol);
        FILE *in = fdopen(dup(fd), "r");
        char *line = NULL;
        size_t cap = 0;
        while (in && getline(&line, &cap, in) > 0) {
                json_t *req = json_loads(line, 0, NULL);
                long long id = json_integer_value(json_object_get(req, "id"));
                const char *cmd = json_string_value(json_object_get(req, "cmd")) ?: "";
                const char *job = json_string_value(json_object_get(json_object_get(req, "args"), "job"));
                if (!strcmp(cmd, "status"))
                        say(fd, "{\"id\":%lld,\"ok\":true,\"result\":{\"daemon\":{\"version\":\"0.1.0\",\"uptime_s\":75,"
                                "\"pid\":42},\"rig\":{\"name\":\"demo\",\"calibrated\":true},\"session\":null,"
                                "\"jobs\":{\"queued\":2,\"running\":1}}}", id);
                else if (!strcmp(cmd, "jobs.show") && job && !strcmp(job, "nope"))
                        say(fd, "{\"id\":%lld,\"ok\":false,\"error\":{\"code\":\"not_found\",\"errno\":2,"
                                "\"message\":\"no job nope\",\"field\":\"args.job\"}}", id);
                else if (!strcmp(cmd, "session.pause"))
                        say(fd, "{\"id\":%lld,\"ok\":false,\"error\":{\"code\":\"permission_denied\",\"errno\":1,"
                                "\"message\":\"session.pause needs the operator role\",\"field\":\"cmd\"}}", id);
                else if (!strcmp(cmd, "devices"))
                        break;   /* the daemon goes away before replying */
                else if (!strcmp(cmd, "subscribe"))
                        say(fd, "{\"id\":%lld,\"ok\":true,\"result\":{\"events\":[\"progress\",\"fault\",\"done\"],"
                                "\"seq\":0}}", id);
                else if (!strcmp(cmd, "session.start")) {
                        say(fd, "{\"event\":\"progress\",\"seq\":1,\"session\":\"s1\",\"step\":1,\"steps\":4,"
                                "\"frames\":1,\"frames_total\":4,\"bytes\":10,\"eta_s\":3.0,\"state\":\"running\"}");
                        say(fd, "{\"id\":%lld,\"ok\":true,\"result\":{\"session\":\"s1\",\"path\":\"/srv/s1\","
                                "\"state\":\"running\"}}", id);
                        say(fd, "{\"event\":\"mystery\",\"seq\":2,\"session\":\"s1\"}");
                        say(fd, "{\"event\":\"progress\",\"seq\":4,\"session\":\"s1\",\"step\":3,\"steps\":4,"
                                "\"frames\":3,\"frames_total\":4,\"bytes\":30,\"eta_s\":1.0,\"state\":\"running\"}");
                        say(fd, "{\"event\":\"done\",\"seq\":5,\"session\":\"s1\",\"state\":\"completed\","
                                "\"frames\":4,\"path\":\"/srv/s1\"}");
                } else
                        say(fd, "{\"id\":%lld,\"ok\":false,\"error\":{\"code\":\"unknown_command\",\"errno\":95,"
                                "\"message\":\"no such command\",\"field\":\"cmd\"}}", id);
                json_decref(req);
        }
        free(line);
        if (in)
                fclose(in);
}

static pid_t serve(int lfd, int protocol) {
        pid_t pid = fork();
        if (pid == 0) {
                for (;;) {
                        int fd = accept(lfd, NULL, NULL);
                        if (fd < 0)
                                _exit(0);
                        serve_one(fd, protocol);
                        close(fd);
                }
        }
        return pid;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        signal(SIGPIPE, SIG_IGN);
        const char *tmp = test_tmpdir();
        char sock[300], old[300], dead[300], cmd[2048];
        snprintf(sock, sizeof sock, "%s/d.sock", tmp);
        snprintf(old, sizeof old, "%s/old.sock", tmp);
        snprintf(dead, sizeof dead, "%s/dead.sock", tmp);
        int lfd = listen_at(sock, true), lold = listen_at(old, true), ldead = listen_at(dead, false);
        pid_t p1 = serve(lfd, 1), p2 = serve(lold, 2);

        char *o[12] = {};
        snprintf(cmd, sizeof cmd, "%s status --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[0]), 0);
        CHECK_STR_CONTAINS(o[0], "rig      demo, calibrated");
        CHECK_STR_CONTAINS(o[0], "2 queued, 1 running");
        snprintf(cmd, sizeof cmd, "IMPASTO_SOCKET=%s %s status --json", sock, IMPASTO);
        CHECK_INT_EQ(run(cmd, &o[1]), 0);
        json_t *j = json_loads(o[1] ? o[1] : "", 0, NULL);
        CHECK_INT_EQ(json_integer_value(json_object_get(json_object_get(j, "daemon"), "pid")), 42);
        json_decref(j);

        snprintf(cmd, sizeof cmd, "%s jobs show nope --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[2]), 3);
        CHECK_STR_CONTAINS(o[2], "not_found: no job nope (args.job)");
        snprintf(cmd, sizeof cmd, "%s scan pause s1 --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[3]), 5);
        CHECK_STR_CONTAINS(o[3], "impasto-operators");
        snprintf(cmd, sizeof cmd, "%s jobs retry j1 --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[4]), 1);
        snprintf(cmd, sizeof cmd, "%s devices --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[5]), 4);
        CHECK_STR_CONTAINS(o[5], "closed the connection");

        /* --follow, not on a terminal: plain progress lines; seq 3 never came */
        snprintf(cmd, sizeof cmd, "%s scan start %s/plan.cfg --name t --follow --socket %s", IMPASTO, tmp, sock);
        CHECK_INT_EQ(run(cmd, &o[6]), 0);
        CHECK_STR_CONTAINS(o[6], "session s1 started");
        CHECK_STR_CONTAINS(o[6], "progress s1: 1/4 frames");
        CHECK_STR_CONTAINS(o[6], "dropped 1");
        CHECK_STR_CONTAINS(o[6], "session s1 completed: 4 frames");
        snprintf(cmd, sizeof cmd, "%s scan start %s/plan.cfg --follow --json --socket %s", IMPASTO, tmp, sock);
        CHECK_INT_EQ(run(cmd, &o[7]), 0);
        CHECK_STR_CONTAINS(o[7], "\"event\":\"done\"");

        /* a daemon of another protocol version; nobody listening; no socket at all */
        snprintf(cmd, sizeof cmd, "%s status --socket %s", IMPASTO, old);
        CHECK_INT_EQ(run(cmd, &o[8]), 1);
        CHECK_STR_CONTAINS(o[8], "protocol 2");
        snprintf(cmd, sizeof cmd, "%s status --socket %s", IMPASTO, dead);
        CHECK_INT_EQ(run(cmd, &o[9]), 4);
        CHECK_STR_CONTAINS(o[9], "is impastod running?");
        snprintf(cmd, sizeof cmd, "%s scan list --socket %s/absent.sock", IMPASTO, tmp);
        CHECK_INT_EQ(run(cmd, &o[10]), 4);
        snprintf(cmd, sizeof cmd, "%s scan pause --socket %s", IMPASTO, sock);
        CHECK_INT_EQ(run(cmd, &o[11]), 2);

        for (size_t i = 0; i < ARRAY_SIZE(o); i++)
                free(o[i]);
        kill(p1, SIGKILL);
        kill(p2, SIGKILL);
        waitpid(p1, NULL, 0);
        waitpid(p2, NULL, 0);
        close(lfd);
        close(lold);
        close(ldead);
        return TEST_DONE();
}
