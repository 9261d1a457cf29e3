/* The daemon's state directory: sessions/<id>/ is a capture set (pipeline/model/captureset.h)
 * plus session.json (plan, name, state, times, faults), written atomically at every state
 * change; jobs/ holds the job files. Free space checks for the capture store, and its
 * writer thread (below). */
#include <dirent.h>
#include <pthread.h>
#include <string.h>
#include <sys/eventfd.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <time.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"

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
        _cleanup_json_ json_t *j = json_pack("{s:s, s:s, s:s, s:s, s:s, s:s?, s:I, s:O, s:s?}",
                                              "session", s->id, "name", s->name, "plan", s->plan_path,
                                              "state", session_state_name(s->state), "started", s->started,
                                              "ended", s->ended[0] ? s->ended : NULL,
                                              "frames_total", (json_int_t) s->frames_total,
                                              "faults", s->faults, "rebuilt", s->rebuilt[0] ? s->rebuilt : NULL);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return imp_json_save_atomic(p, j, err);
}

/* Frames of a set, counted cheaply from its manifest's complete lines (for listings; resume
 * reopens properly). */
static size_t count_manifest_lines(const char *dir) {
        char p[2 * PATH_MAX];
        snprintf(p, sizeof p, "%s/manifest.jsonl", dir);
        _cleanup_fclose_ FILE *m = fopen(p, "re");
        size_t n = 0;
        int c, prev = '\n';
        while (m && (c = fgetc(m)) != EOF) {
                if (c == '\n' && prev != '\n')
                        n++;
                prev = c;
        }
        return n;
}

/* A painting's session directory: the frames of its tile sets (tiles/NNNN, in order; a
 * symbolic link is not a tile set and is not followed). */
static size_t count_frames(const char *dir) {
        if (!painting_session_dir(dir))
                return count_manifest_lines(dir);
        size_t n = 0;
        for (size_t k = 0; k < IMP_TILES_MAX; k++) {
                char p[PATH_MAX + 32];
                struct stat st;
                snprintf(p, sizeof p, "%.4000s/tiles/%04zu", dir, k);
                if (lstat(p, &st) < 0 || !S_ISDIR(st.st_mode))
                        break;
                n += count_manifest_lines(p);
        }
        return n;
}

static struct session *session_new_loaded(struct daemon *d, const char *dir, const char *id) {
        struct session *s = calloc(1, sizeof *s);
        if (!s)
                return NULL;
        s->d = d;
        snprintf(s->id, sizeof s->id, "%s", id);
        snprintf(s->dir, sizeof s->dir, "%.4000s", dir);
        s->shown_pattern = -1;
        s->current_tile = -1;
        s->cs_tile = -1;
        return s;
}

/* session.json as saved by store_session_save; -EBADMSG with e naming what is wrong. */
static int load_session_json(struct session *s, struct imp_error *e) {
        char p[2 * PATH_MAX];
        snprintf(p, sizeof p, "%s/session.json", s->dir);
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(p, &j, e);
        if (r < 0)
                return r;
        const char *name = "", *plan = "", *state = "", *started = "", *ended = NULL, *rebuilt = NULL;
        long long total = 0;
        if (imp_json_get_string(j, "name", false, &name, p, e) < 0 ||
            imp_json_get_string(j, "plan", false, &plan, p, e) < 0 ||
            imp_json_get_string(j, "state", true, &state, p, e) < 0 ||
            imp_json_get_string(j, "started", false, &started, p, e) < 0 ||
            imp_json_get_string(j, "ended", false, &ended, p, e) < 0 ||
            imp_json_get_int(j, "frames_total", false, &total, p, e) < 0 ||
            imp_json_get_string(j, "rebuilt", false, &rebuilt, p, e) < 0)
                return -EBADMSG;
        int st = session_state_from_name(state);
        if (st < 0 || total < 0)
                return imp_error_set(e, -EBADMSG, "%s: state: \"%s\" is not a session state", p, state);
        /* what the daemon wrote fits its buffers; a longer string (a hand-edited file) would be
         * cut, maybe inside a character, and the session could neither be listed nor saved */
        const struct {
                const char *key, *v;
                size_t max;
        } str[] = { { "name", name, sizeof s->name - 1 }, { "plan", plan, sizeof s->plan_path - 1 },
                    { "started", started, sizeof s->started - 1 }, { "ended", ended ? ended : "", sizeof s->ended - 1 },
                    { "rebuilt", rebuilt ? rebuilt : "", 2000 } };
        for (size_t i = 0; i < ARRAY_SIZE(str); i++)
                if (strlen(str[i].v) > str[i].max)
                        return imp_error_set(e, -EBADMSG, "%s: %s: expected at most %zu bytes, got %zu", p, str[i].key,
                                             str[i].max, strlen(str[i].v));
        snprintf(s->name, sizeof s->name, "%s", name);
        snprintf(s->plan_path, sizeof s->plan_path, "%s", plan);
        snprintf(s->started, sizeof s->started, "%s", started);
        snprintf(s->ended, sizeof s->ended, "%s", ended ? ended : "");
        snprintf(s->rebuilt, sizeof s->rebuilt, "%.2000s", rebuilt ? rebuilt : "");
        s->frames_total = (size_t) total;
        s->state = (enum session_state) st;
        json_t *f = json_object_get(j, "faults");
        s->faults = json_is_array(f) ? json_incref(f) : json_array();
        return 0;
}

/* A painting's session listed as damaged: where it stands (read only: plan.cfg against
 * rig.json, the tile sets' manifests), e.g. "34 of 60 frames: tile 3 of 6 at its frame 4 of
 * 10"; empty when plan.cfg or rig.json cannot be read (the resume then says why). */
static void painting_where(struct session *s, size_t n_frames, char *buf, size_t size) {
        char p[PATH_MAX + 32];
        struct imp_rig rig = { 0 };
        struct imp_error e = { 0 };
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        buf[0] = 0;
        snprintf(p, sizeof p, "%.4000s/rig.json", s->dir);
        if (imp_rig_load(p, &rig, &e) < 0)
                return;
        snprintf(p, sizeof p, "%.4000s/plan.cfg", s->dir);
        if (imp_plan_load(p, &rig, &plan, &e) == 0 && imp_plan_tiles(plan) && imp_plan_count(plan) > 0) {
                size_t per = imp_plan_count(plan), n = imp_tile_plan_count(imp_plan_tiles(plan));
                s->frames_total = n * per;
                size_t k = IMP_MIN(n_frames / per, n - 1);
                snprintf(buf, size, "%zu of %zu frames: tile %zu of %zu at its frame %zu of %zu", n_frames,
                         s->frames_total, k, n, n_frames - k * per, per);
        }
        imp_rig_free(&rig);
}

/* A session whose session.json is damaged or missing does not vanish while its set (or its
 * painting directory: painting.json, tiles/NNNN) is on disk: it is listed as paused and
 * damaged, never resumed by itself; session.resume rebuilds it from the set's manifest and
 * plan.cfg, or from the painting's tile sets (reopen), and saves a new session.json. */
static int load_damaged(struct session *s, const struct imp_error *why) {
        char p[2 * PATH_MAX], where[200] = "";
        bool painting = painting_session_dir(s->dir);
        snprintf(p, sizeof p, "%s/set.json", s->dir);
        if (!painting && access(p, F_OK) < 0)
                return -ENOENT;         /* not a capture set either: nothing to recover */
        if (painting)
                painting_where(s, count_frames(s->dir), where, sizeof where);
        snprintf(s->damaged, sizeof s->damaged, "%.400s%s%.100s", why->msg[0] ? why->msg : "session.json is unreadable",
                 where[0] ? "; " : "", where);
        snprintf(s->name, sizeof s->name, "%.64s", s->id);
        snprintf(s->plan_path, sizeof s->plan_path, "%.4000s/plan.cfg", s->dir);
        s->state = SESSION_PAUSED;
        s->faults = json_array();
        log_warning("session %s: %s: listed as damaged; `impasto scan resume %s` rebuilds it from the %s", s->id,
                    s->damaged, s->id, painting ? "painting's tile sets and plan" : "capture set's manifest and plan");
        return 0;
}

static int load_one(struct daemon *d, const char *dir, const char *id) {
        struct session *s = session_new_loaded(d, dir, id);
        if (!s)
                return -ENOMEM;
        struct imp_error e = { 0 };
        int r = load_session_json(s, &e);
        if (r < 0 && (r = load_damaged(s, &e)) < 0) {
                log_warning("%s: no session.json and no capture set (%s), ignoring", dir, e.msg);
                session_free(s);
                return r;
        }
        if (!s->damaged[0] && (s->state == SESSION_CAPTURING || s->state == SESSION_PREPARING)) {
                /* The daemon stopped (or died) while this session ran. */
                s->state = SESSION_PAUSED;
                s->interrupted = true;
        }
        s->n_frames = count_frames(dir);
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
                char sd[PATH_MAX + 300], probe[256];
                /* a session id fits its buffer and is valid UTF-8 (clients get it in JSON);
                 * a folder someone named otherwise is left alone, not listed under a cut name */
                snprintf(probe, sizeof probe, "%s", names[i] ? names[i] : "");
                if (names[i] && (strlen(names[i]) >= sizeof ((struct session *) NULL)->id || imp_utf8_sanitize(probe))) {
                        log_warning("%s/%s: not a session id (at most %zu bytes of UTF-8), ignoring", p, probe,
                                    sizeof ((struct session *) NULL)->id - 1);
                        free(names[i]);
                        continue;
                }
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

/* ---- the store writer ------------------------------------------------------------------ */

struct store_item {
        struct store_item *next;
        struct imp_frame_record rec;
        struct imp_image *img;
        long long pixel_bytes;
        int r;
        char msg[1024];
};

/* Stored images kept for the next frames (store_writer_spare_image). */
#define STORE_SPARE_IMAGES 4

struct store_writer {
        pthread_mutex_t lock;
        pthread_cond_t work;            /* an item queued, or stop */
        pthread_cond_t idle;            /* the queue ran empty */
        pthread_t thread;
        struct imp_captureset *cs;      /* used by the thread alone while it holds items */
        struct store_item *todo, **todo_tail;   /* queued, in order */
        struct store_item *done, **done_tail;   /* finished, not yet delivered */
        unsigned held;                  /* queued or being written: their images are in memory */
        uint64_t held_bytes;
        bool busy, failed, stop;
        int efd;                        /* the thread → event loop doorbell */
        sd_event_source *source;
        store_done_fn done_fn;
        void *userdata;
        bool delivering, free_pending;
        struct imp_image *spare[STORE_SPARE_IMAGES];
        unsigned n_spare;
};

static void store_items_free(struct store_item *it) {
        while (it) {
                struct store_item *next = it->next;
                imp_image_free(it->img);
                free(it);
                it = next;
        }
}

static void *writer_main(void *userdata) {
        struct store_writer *w = userdata;
        pthread_mutex_lock(&w->lock);
        for (;;) {
                while (!w->todo && !w->stop)
                        pthread_cond_wait(&w->work, &w->lock);
                struct store_item *it = w->todo;
                if (!it)
                        break;
                w->todo = it->next;
                if (!w->todo)
                        w->todo_tail = &w->todo;
                it->next = NULL;
                bool drop = w->failed;
                w->busy = true;
                pthread_mutex_unlock(&w->lock);

                uint64_t held_bytes = (uint64_t) it->img->stride * (uint64_t) it->img->height;
                if (!drop) {
                        struct imp_error e = { 0 };
                        it->r = imp_captureset_add_frame(w->cs, &it->rec, it->img, &e);
                        if (it->r < 0)
                                snprintf(it->msg, sizeof it->msg, "%s", e.msg[0] ? e.msg : strerror(-it->r));
                }
                it->pixel_bytes = (long long) held_bytes;
                struct imp_image *img = TAKE_PTR(it->img);

                pthread_mutex_lock(&w->lock);
                if (w->n_spare < STORE_SPARE_IMAGES)
                        w->spare[w->n_spare++] = TAKE_PTR(img);
                w->busy = false;
                w->held--;
                w->held_bytes -= held_bytes;
                if (drop)
                        free(it);       /* never in the manifest: captured again on resume */
                else {
                        if (it->r < 0)
                                w->failed = true;
                        *w->done_tail = it;
                        w->done_tail = &it->next;
                        (void) eventfd_write(w->efd, 1);
                }
                if (!w->todo)
                        pthread_cond_broadcast(&w->idle);
                if (img) {
                        pthread_mutex_unlock(&w->lock);
                        imp_image_free(img);
                        pthread_mutex_lock(&w->lock);
                }
        }
        pthread_mutex_unlock(&w->lock);
        return NULL;
}

static void writer_destroy(struct store_writer *w) {
        pthread_mutex_lock(&w->lock);
        w->stop = true;
        pthread_cond_signal(&w->work);
        pthread_mutex_unlock(&w->lock);
        pthread_join(w->thread, NULL);
        store_items_free(w->todo);
        store_items_free(w->done);
        while (w->n_spare > 0)
                imp_image_free(w->spare[--w->n_spare]);
        sd_event_source_disable_unref(w->source);
        close(w->efd);
        pthread_cond_destroy(&w->idle);
        pthread_cond_destroy(&w->work);
        pthread_mutex_destroy(&w->lock);
        free(w);
}

/* Results in order, on the event loop. A `done` callback may flush or free the writer:
 * nested deliveries are left to this loop, a free to its end. */
static void writer_deliver(struct store_writer *w) {
        if (w->delivering)
                return;
        w->delivering = true;
        for (;;) {
                pthread_mutex_lock(&w->lock);
                struct store_item *it = w->done;
                if (it) {
                        w->done = it->next;
                        if (!w->done)
                                w->done_tail = &w->done;
                }
                pthread_mutex_unlock(&w->lock);
                if (!it)
                        break;
                w->done_fn(w->userdata, &it->rec, it->pixel_bytes, it->r, it->msg);
                free(it);
        }
        w->delivering = false;
        if (w->free_pending)
                writer_destroy(w);
}

static int on_writer_event(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        eventfd_t v;
        (void) eventfd_read(fd, &v);
        writer_deliver(userdata);
        return 0;
}

int store_writer_new(sd_event *event, struct imp_captureset *cs, store_done_fn done, void *userdata,
                     struct store_writer **ret) {
        struct store_writer *w = calloc(1, sizeof *w);
        if (!w)
                return -ENOMEM;
        w->cs = cs;
        w->done_fn = done;
        w->userdata = userdata;
        w->todo_tail = &w->todo;
        w->done_tail = &w->done;
        pthread_mutex_init(&w->lock, NULL);
        pthread_cond_init(&w->work, NULL);
        pthread_cond_init(&w->idle, NULL);
        int r;
        w->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
        if (w->efd < 0)
                r = negative_errno();
        else
                r = sd_event_add_io(event, &w->source, w->efd, EPOLLIN, on_writer_event, w);
        if (r >= 0)
                r = -pthread_create(&w->thread, NULL, writer_main, w);
        if (r < 0) {
                sd_event_source_disable_unref(w->source);
                if (w->efd >= 0)
                        close(w->efd);
                pthread_cond_destroy(&w->idle);
                pthread_cond_destroy(&w->work);
                pthread_mutex_destroy(&w->lock);
                free(w);
                return r;
        }
        *ret = w;
        return 0;
}

int store_writer_push(struct store_writer *w, const struct imp_frame_record *rec, struct imp_image *img) {
        struct store_item *it = calloc(1, sizeof *it);
        if (!it) {
                imp_image_free(img);
                return -ENOMEM;
        }
        it->rec = *rec;
        it->img = img;
        pthread_mutex_lock(&w->lock);
        if (w->failed) {
                pthread_mutex_unlock(&w->lock);
                store_items_free(it);
                return -EIO;
        }
        *w->todo_tail = it;
        w->todo_tail = &it->next;
        w->held++;
        w->held_bytes += (uint64_t) img->stride * (uint64_t) img->height;
        pthread_cond_signal(&w->work);
        pthread_mutex_unlock(&w->lock);
        return 0;
}

bool store_writer_full(const struct store_writer *w) {
        if (!w)
                return false;
        struct store_writer *m = (struct store_writer *) w;     /* the lock only */
        pthread_mutex_lock(&m->lock);
        bool full = w->held > 0 && (w->held >= STORE_QUEUE_MAX_FRAMES || w->held_bytes >= STORE_QUEUE_MAX_BYTES);
        pthread_mutex_unlock(&m->lock);
        return full;
}

struct imp_image *store_writer_spare_image(struct store_writer *w, int width, int height) {
        struct imp_image *img = NULL, *stale = NULL;
        if (!w)
                return NULL;
        pthread_mutex_lock(&w->lock);
        if (w->n_spare > 0) {
                img = w->spare[--w->n_spare];
                if (img->width != width || img->height != height || img->channels != 1 || img->type != IMP_PIX_U16)
                        stale = TAKE_PTR(img);
        }
        pthread_mutex_unlock(&w->lock);
        imp_image_free(stale);
        return img;
}

void store_writer_flush(struct store_writer *w) {
        if (!w)
                return;
        pthread_mutex_lock(&w->lock);
        while (w->todo || w->busy)
                pthread_cond_wait(&w->idle, &w->lock);
        pthread_mutex_unlock(&w->lock);
        writer_deliver(w);
        pthread_mutex_lock(&w->lock);
        w->failed = false;
        pthread_mutex_unlock(&w->lock);
}

void store_writer_free(struct store_writer *w) {
        if (!w)
                return;
        store_writer_flush(w);
        if (w->delivering)
                w->free_pending = true;
        else
                writer_destroy(w);
}
