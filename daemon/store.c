/* The daemon's state directory: sessions/<id>/ is a capture set (pipeline/captureset.h)
 * plus session.json (plan, name, state, times, faults), written atomically at every state
 * change; jobs/ holds the job files. Free space checks for the capture store. */
#include <dirent.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <time.h>
#include "impastod.h"
#include "json-util.h"

void rfc3339_now(char buf[static 32]) {
        time_t t = time(NULL);
        struct tm tm;
        gmtime_r(&t, &tm);
        strftime(buf, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
}

int store_init(const char *state_dir, struct imp_error *err) {
        char p[PATH_MAX];
        int r;
        snprintf(p, sizeof p, "%s/sessions", state_dir);
        if ((r = imp_mkdir_p(p, 0750)) < 0)
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        snprintf(p, sizeof p, "%s/jobs", state_dir);
        if ((r = imp_mkdir_p(p, 0750)) < 0)
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        return 0;
}

int store_session_save(const struct session *s, struct imp_error *err) {
        char p[PATH_MAX + 16];
        snprintf(p, sizeof p, "%s/session.json", s->dir);
        _cleanup_json_ json_t *j = json_pack("{s:s, s:s, s:s, s:s, s:s, s:s?, s:I, s:O}",
                                              "session", s->id, "name", s->name, "plan", s->plan_path,
                                              "state", session_state_name(s->state), "started", s->started,
                                              "ended", s->ended[0] ? s->ended : NULL,
                                              "frames_total", (json_int_t) s->frames_total,
                                              "faults", s->faults);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return imp_json_save_atomic(p, j, err);
}

static int load_one(struct daemon *d, const char *dir, const char *id) {
        char p[2 * PATH_MAX];
        snprintf(p, sizeof p, "%s/session.json", dir);
        _cleanup_json_ json_t *j = NULL;
        struct imp_error e = { 0 };
        int r = imp_json_load(p, &j, &e);
        if (r < 0)
                return r;
        const char *name = "", *plan = "", *state = "", *started = "", *ended = NULL;
        long long total = 0;
        if (imp_json_get_string(j, "name", false, &name, p, &e) < 0 ||
            imp_json_get_string(j, "plan", false, &plan, p, &e) < 0 ||
            imp_json_get_string(j, "state", true, &state, p, &e) < 0 ||
            imp_json_get_string(j, "started", false, &started, p, &e) < 0 ||
            imp_json_get_string(j, "ended", false, &ended, p, &e) < 0 ||
            imp_json_get_int(j, "frames_total", false, &total, p, &e) < 0)
                return -EINVAL;
        int st = session_state_from_name(state);
        if (st < 0)
                return -EINVAL;
        struct session *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->d = d;
        snprintf(s->id, sizeof s->id, "%s", id);
        snprintf(s->name, sizeof s->name, "%s", name);
        snprintf(s->plan_path, sizeof s->plan_path, "%s", plan);
        snprintf(s->dir, sizeof s->dir, "%.4000s", dir);
        snprintf(s->started, sizeof s->started, "%s", started);
        snprintf(s->ended, sizeof s->ended, "%s", ended ? ended : "");
        s->frames_total = (size_t) total;
        s->state = (enum session_state) st;
        s->shown_pattern = -1;
        s->current_tile = -1;
        json_t *f = json_object_get(j, "faults");
        s->faults = json_is_array(f) ? json_incref(f) : json_array();
        if (s->state == SESSION_CAPTURING || s->state == SESSION_PREPARING) {
                /* The daemon stopped (or died) while this session ran. */
                s->state = SESSION_PAUSED;
                s->interrupted = true;
        }
        /* Count frames cheaply from the manifest for listings; resume reopens properly. */
        snprintf(p, sizeof p, "%s/manifest.jsonl", dir);
        FILE *m = fopen(p, "re");
        if (m) {
                int c, prev = '\n';
                while ((c = fgetc(m)) != EOF) {
                        if (c == '\n' && prev != '\n')
                                s->n_frames++;
                        prev = c;
                }
                fclose(m);
        }
        s->next = d->sessions;
        d->sessions = s;
        return 0;
}

static int cmp_names(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

int store_sessions_load(struct daemon *d) {
        char p[PATH_MAX];
        snprintf(p, sizeof p, "%s/sessions", d->state_dir);
        DIR *dir = opendir(p);
        if (!dir)
                return negative_errno();
        char **names = NULL;
        size_t n = 0;
        struct dirent *de;
        while ((de = readdir(dir))) {
                if (de->d_name[0] == '.')
                        continue;
                char **nn = realloc(names, (n + 1) * sizeof *names);
                if (!nn)
                        break;
                names = nn;
                names[n++] = strdup(de->d_name);
        }
        closedir(dir);
        if (n > 0)   /* qsort(NULL, 0, …) is undefined behaviour */
                qsort(names, n, sizeof *names, cmp_names);
        int loaded = 0;
        for (size_t i = 0; i < n; i++) {
                char sd[PATH_MAX + 300];
                if (names[i]) {
                        snprintf(sd, sizeof sd, "%s/%s", p, names[i]);
                        if (load_one(d, sd, names[i]) == 0)
                                loaded++;
                }
                free(names[i]);
        }
        free(names);
        return loaded;
}

int store_free_bytes(const char *path, uint64_t *ret) {
        struct statvfs sv;
        if (statvfs(path, &sv) < 0)
                return negative_errno();
        *ret = (uint64_t) sv.f_bavail * sv.f_frsize;
        return 0;
}

/* 16-bit TIFF of the calibrated size plus headers and the manifest line. */
uint64_t store_frame_bytes(const struct imp_rig *rig, const char *camera) {
        for (int i = 0; i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, camera))
                        return (uint64_t) rig->cameras[i].model.width * rig->cameras[i].model.height * 2 + 4096;
        return 4096;
}
