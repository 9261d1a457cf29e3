/* The job file (job.h, docs/jobs.md). */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include "job.h"
#include "json-util.h"
#include "macro.h"

static const char *const state_names[_IMP_JOB_STATE_MAX] = { "queued", "running", "done", "failed" };

const char *imp_job_state_name(enum imp_job_state s) {
        return s < _IMP_JOB_STATE_MAX ? state_names[s] : "?";
}

int imp_job_state_from_name(const char *s) {
        for (size_t i = 0; s && i < ARRAY_SIZE(state_names); i++)
                if (!strcmp(s, state_names[i]))
                        return (int) i;
        return -EINVAL;
}

bool imp_job_id_valid(const char *s) {
        size_t n = strlen(s);
        if (n < 1 || n > IMP_JOB_ID_MAX || s[0] == '.')
                return false;
        for (; *s; s++)
                if (!(('a' <= *s && *s <= 'z') || ('A' <= *s && *s <= 'Z') || ('0' <= *s && *s <= '9') ||
                      *s == '.' || *s == '_' || *s == '-'))
                        return false;
        return true;
}

static void copy_str(char *dst, size_t size, const json_t *o, const char *key) {
        const char *v = json_string_value(json_object_get(o, key));
        snprintf(dst, size, "%s", v ? v : "");
}

/* The worker's checks of docs/jobs.md. */
static int check_strict(const json_t *doc, const char *path, struct imp_error *err) {
        const char *id, *capture, *copy, *state;
        long long attempts = 0, max_attempts = IMP_JOB_DEFAULT_MAX_ATTEMPTS;
        int r;
        if ((r = imp_json_get_string(doc, "id", true, &id, path, err)) < 0 ||
            (r = imp_json_get_string(doc, "capture", true, &capture, path, err)) < 0 ||
            (r = imp_json_get_string(doc, "copy", true, &copy, path, err)) < 0 ||
            (r = imp_json_get_string(doc, "state", true, &state, path, err)) < 0 ||
            (r = imp_json_get_int(doc, "attempts", false, &attempts, path, err)) < 0 ||
            (r = imp_json_get_int(doc, "max_attempts", false, &max_attempts, path, err)) < 0)
                return r == -ENOENT ? -EINVAL : r;
        if (!imp_job_id_valid(id))
                return imp_error_set(err, -EINVAL, "%s: id: expected 1 to 128 of [A-Za-z0-9._-], got \"%s\"", path, id);
        if (!capture[0] || !copy[0])
                return imp_error_set(err, -EINVAL, "%s: %s: expected a path", path, capture[0] ? "copy" : "capture");
        if (attempts < 0 || attempts > INT_MAX)
                return imp_error_set(err, -EINVAL, "%s: attempts: expected an integer >= 0, got %lld", path, attempts);
        if (max_attempts < 1 || max_attempts > IMP_JOB_MAX_ATTEMPTS_LIMIT)
                return imp_error_set(err, -EINVAL, "%s: max_attempts: expected 1 to %d, got %lld", path,
                                     IMP_JOB_MAX_ATTEMPTS_LIMIT, max_attempts);
        return 0;
}

static int check_lenient(const json_t *doc, const char *path, struct imp_error *err) {
        const json_t *capture = json_object_get(doc, "capture"), *set = json_object_get(doc, "set");
        if (imp_job_state_from_name(json_string_value(json_object_get(doc, "state"))) < 0 ||
            !(json_is_string(capture) || json_is_string(set)))
                return imp_error_set(err, -EBADMSG, "%s: not a job file (docs/jobs.md)", path);
        return 0;
}

static void fill(struct imp_job *j, enum imp_job_parse_mode mode) {
        const json_t *o = j->doc;
        copy_str(j->id, sizeof j->id, o, "id");
        j->legacy = mode == IMP_JOB_LENIENT && !json_is_string(json_object_get(o, "capture"));
        copy_str(j->capture, sizeof j->capture, o, j->legacy ? "set" : "capture");
        copy_str(j->copy, sizeof j->copy, o, "copy");
        copy_str(j->session, sizeof j->session, o, "session");
        copy_str(j->queued, sizeof j->queued, o, "queued");
        copy_str(j->started, sizeof j->started, o, "started");
        copy_str(j->ended, sizeof j->ended, o, "ended");
        copy_str(j->stage, sizeof j->stage, o, "stage");
        j->state = (enum imp_job_state) imp_job_state_from_name(json_string_value(json_object_get(o, "state")));
        const json_t *e = json_object_get(o, "error");
        if (json_is_object(e))          /* impastod's old format kept an error object */
                e = json_object_get(e, "message");
        snprintf(j->error, sizeof j->error, "%s", json_is_string(e) ? json_string_value(e) : "");
        json_t *v = json_object_get(o, "attempts");
        j->attempts = json_is_integer(v) ? (int) json_integer_value(v) : 0;
        v = json_object_get(o, "max_attempts");
        /* (strict mode checked the range) */
        j->max_attempts = json_is_integer(v) && json_integer_value(v) >= 1 ? (int) IMP_MIN(json_integer_value(v), INT_MAX)
                          : mode == IMP_JOB_STRICT ? IMP_JOB_DEFAULT_MAX_ATTEMPTS : 0;
        v = json_object_get(o, "progress");
        j->progress = json_is_number(v) ? IMP_CLAMP(json_number_value(v), 0.0, 1.0) : 0.0;
        v = json_object_get(o, "worker_args");
        j->worker_args = json_is_string(v) ? v : NULL;
}

int imp_job_parse(json_t *doc, const char *path, enum imp_job_parse_mode mode, struct imp_job *j,
                  struct imp_error *err) {
        *j = (struct imp_job) { 0 };
        int r = !json_is_object(doc) ? imp_error_set(err, mode == IMP_JOB_STRICT ? -EINVAL : -EBADMSG,
                                                     "%s: expected a JSON object", path)
                : mode == IMP_JOB_STRICT ? check_strict(doc, path, err) : check_lenient(doc, path, err);
        if (r < 0) {
                json_decref(doc);
                return r;
        }
        j->doc = doc;
        fill(j, mode);
        return 0;
}

int imp_job_read(const char *path, enum imp_job_parse_mode mode, struct imp_job *j, struct imp_error *err) {
        json_t *doc = NULL;
        *j = (struct imp_job) { 0 };
        int r = imp_json_load(path, &doc, err);
        if (r < 0)
                return r;
        return imp_job_parse(doc, path, mode, j, err);
}

void imp_job_done(struct imp_job *j) {
        json_decref(j->doc);
        j->doc = NULL;
        j->worker_args = NULL;
}

int imp_job_path(const char *dir, const char *id, enum imp_job_file which, char *buf, size_t size) {
        static const char *const suffix[] = { ".json", ".json.running", ".lock" };
        int n = snprintf(buf, size, "%s/%s%s", dir, id, suffix[which]);
        return n < 0 || (size_t) n >= size ? -ENAMETOOLONG : 0;
}

int imp_job_lock(const char *p, int *ret_fd) {
        for (;;) {
                int fd = open(p, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
                if (fd < 0)
                        return negative_errno();
                if (flock(fd, LOCK_EX | LOCK_NB) < 0) {
                        int r = errno == EWOULDBLOCK ? -EBUSY : negative_errno();
                        close(fd);
                        return r;
                }
                struct stat a, b;
                if (fstat(fd, &a) == 0 && stat(p, &b) == 0 && a.st_ino == b.st_ino && a.st_dev == b.st_dev) {
                        *ret_fd = fd;
                        return 0;
                }
                close(fd);      /* unlinked under us: take the new one */
        }
}

void imp_job_unlock(const char *p, int fd) {
        (void) unlink(p);
        close(fd);
}

void imp_rfc3339_now(char buf[static 32]) {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        struct tm tm;
        gmtime_r(&ts.tv_sec, &tm);
        strftime(buf, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}
