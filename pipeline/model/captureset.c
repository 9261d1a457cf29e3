/* Capture sets on disk (docs/capture-set.md): frames written crash-safely, then recorded
 * in an append-only JSON-lines manifest. open() never changes a set: it reads, and refuses
 * what it cannot explain; repair() is the explicit step that moves what a crash left behind
 * (a torn last line, an unrecorded frame, a .tmp) into quarantine/, never deleting. */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>
#include "captureset.h"
#include "json-util.h"
#include "plan.h"

#define SET_FORMAT "impasto-capture-set"
#define SET_VERSION 1
#define MANIFEST "manifest.jsonl"
#define FRAMES_DIR "frames"
#define MANIFEST_LINE_MAX_BYTES (64 * 1024)
#define IO_CHUNK_BYTES (64 * 1024)

struct imp_captureset {
        char *dir;
        struct imp_rig rig;
        struct imp_frame_record *recs;
        long long *sizes_bytes;        /* file size of each frame, from the manifest */
        size_t n, cap;
        int manifest_fd;               /* O_APPEND, flock(LOCK_EX) held while writable */
        off_t manifest_bytes;          /* length of the valid manifest */
        int read_only;                 /* 0, or why not writable (-EBUSY, -EROFS, -EACCES) */
};

/* ---- records ---- */

static const char *const pattern_kinds[] = {
        [IMP_PAT_NONE] = NULL, [IMP_PAT_WHITE] = "white", [IMP_PAT_BLACK] = "black",
        [IMP_PAT_GRAY] = "gray", [IMP_PAT_PHASE] = "phase",
};

static json_t *pattern_to_json(const struct imp_pattern *p) {
        const char *axis = p->axis ? "y" : "x";
        switch (p->kind) {
        case IMP_PAT_GRAY:
                return json_pack("{s:s, s:s, s:i, s:i, s:b}", "kind", "gray", "axis", axis,
                                 "bit", p->bit, "nbits", p->nbits, "inverse", (int) p->inverse);
        case IMP_PAT_PHASE:
                return json_pack("{s:s, s:s, s:f, s:i, s:i}", "kind", "phase", "axis", axis,
                                 "period_px", p->period_px, "step", p->step, "steps", p->steps);
        case IMP_PAT_WHITE:
        case IMP_PAT_BLACK:
                return json_pack("{s:s}", "kind", pattern_kinds[p->kind]);
        default:
                return json_null();
        }
}

static int get_ranged_int(const json_t *o, const char *key, long long min, long long max,
                          long long *ret, const char *what, struct imp_error *err) {
        long long v = 0;
        int r = imp_json_get_int(o, key, true, &v, what, err);
        if (r < 0)
                return r;
        size_t n = strlen(what);
        const char *sep = n && (what[n - 1] == '.' || what[n - 1] == ' ') ? "" : ": ";
        if (v < min || v > max)
                return imp_error_set(err, -EINVAL, "%s%s%s: expected an integer in [%lld, %lld], got %lld",
                                     what, sep, key, min, max, v);
        *ret = v;
        return 0;
}

static int pattern_from_json(const json_t *j, const char *what, struct imp_pattern *ret,
                             struct imp_error *err) {
        struct imp_pattern p = { .kind = IMP_PAT_NONE };
        if (!j || json_is_null(j)) {
                *ret = p;
                return 0;
        }
        char w[320];
        snprintf(w, sizeof w, "%s: pattern.", what);
        if (!json_is_object(j))
                return imp_error_set(err, -EINVAL, "%s: pattern: expected an object or null", what);
        const char *kind, *axis = NULL;
        int r = imp_json_get_string(j, "kind", true, &kind, w, err);
        if (r < 0)
                return r;
        for (int k = IMP_PAT_WHITE; k <= IMP_PAT_PHASE; k++)
                if (strcmp(kind, pattern_kinds[k]) == 0)
                        p.kind = (enum imp_pattern_kind) k;
        if (p.kind == IMP_PAT_NONE)
                return imp_error_set(err, -EINVAL, "%skind: expected \"gray\", \"phase\", \"white\" "
                                     "or \"black\", got \"%s\"", w, kind);
        if (p.kind == IMP_PAT_WHITE || p.kind == IMP_PAT_BLACK) {
                *ret = p;
                return 0;
        }
        if ((r = imp_json_get_string(j, "axis", true, &axis, w, err)) < 0)
                return r;
        if (strcmp(axis, "x") && strcmp(axis, "y"))
                return imp_error_set(err, -EINVAL, "%saxis: expected \"x\" or \"y\", got \"%s\"", w, axis);
        p.axis = axis[0] == 'y';
        long long a, b;
        if (p.kind == IMP_PAT_GRAY) {
                json_t *inv = json_object_get(j, "inverse");
                if ((r = get_ranged_int(j, "nbits", 1, 30, &b, w, err)) < 0 ||
                    (r = get_ranged_int(j, "bit", 0, b - 1, &a, w, err)) < 0)
                        return r;
                if (!json_is_boolean(inv))
                        return imp_error_set(err, inv ? -EINVAL : -ENOENT, "%sinverse: %s", w,
                                             inv ? "expected true or false" : "missing (required)");
                p.nbits = (int) b;
                p.bit = (int) a;
                p.inverse = json_is_true(inv);
        } else {
                if ((r = imp_json_get_double(j, "period_px", true, &p.period_px, w, err)) < 0)
                        return r;
                if (!(p.period_px > 0 && p.period_px < 1e9))
                        return imp_error_set(err, -EINVAL, "%speriod_px: expected a number > 0, got %g",
                                             w, p.period_px);
                if ((r = get_ranged_int(j, "steps", 1, 1 << 16, &b, w, err)) < 0 ||
                    (r = get_ranged_int(j, "step", 0, b - 1, &a, w, err)) < 0)
                        return r;
                p.steps = (int) b;
                p.step = (int) a;
        }
        *ret = p;
        return 0;
}

static json_t *stage_to_json(const struct imp_frame_record *rec) {
        const double *c = rec->stage_commanded_mm, *b = rec->stage_readback_mm;
        return json_pack("{s:[f,f,f], s:[f,f,f]}", "commanded_mm", c[0], c[1], c[2], "readback_mm", b[0], b[1], b[2]);
}

json_t *imp_frame_record_to_json(const struct imp_frame_record *rec) {
        json_t *j = json_pack("{s:I, s:s, s:s, s:i, s:o, s:i, s:i, s:f, s:f, s:I, s:I, s:I, s:s, s:I}",
                         "seq", (json_int_t) rec->seq, "step", rec->step, "camera", rec->camera,
                         "tile", rec->tile, "pattern", pattern_to_json(&rec->pattern),
                         "light", rec->light, "exposure_index", rec->exposure_index,
                         "exposure_us", rec->exposure_us, "gain_db", rec->gain_db,
                         "t_light_on_ns", (json_int_t) rec->t_light_on_ns,
                         "t_trigger_ns", (json_int_t) rec->t_trigger_ns,
                         "t_frame_ns", (json_int_t) rec->t_frame_ns, "file", rec->file,
                         "crc32", (json_int_t) rec->crc32);
        if (j && rec->has_stage)
                json_object_set_new(j, "stage", stage_to_json(rec));
        return j;
}

static int get_text(const json_t *j, const char *key, char *buf, size_t size, const char *what,
                    struct imp_error *err) {
        const char *s;
        int r = imp_json_get_string(j, key, true, &s, what, err);
        if (r < 0)
                return r;
        if (strlen(s) >= size)
                return imp_error_set(err, -EINVAL, "%s: %s: expected at most %zu characters, got %zu",
                                     what, key, size - 1, strlen(s));
        strcpy(buf, s);
        return 0;
}

int imp_frame_record_from_json(const json_t *j, const char *what, struct imp_frame_record *ret,
                               struct imp_error *err) {
        struct imp_frame_record rec = {};
        long long v = 0;
        int r;
        if (!json_is_object(j))
                return imp_error_set(err, -EINVAL, "%s: expected a JSON object", what);
        if ((r = get_ranged_int(j, "seq", 0, INT64_MAX, &rec.seq, what, err)) < 0 ||
            (r = get_text(j, "step", rec.step, sizeof rec.step, what, err)) < 0 ||
            (r = get_text(j, "camera", rec.camera, sizeof rec.camera, what, err)) < 0)
                return r;
        if ((r = get_ranged_int(j, "tile", 0, INT32_MAX, &v, what, err)) < 0)
                return r;
        rec.tile = (int) v;
        if (!json_object_get(j, "pattern"))
                return imp_error_set(err, -ENOENT, "%s: pattern: missing (required; null for none)",
                                     what);
        if ((r = pattern_from_json(json_object_get(j, "pattern"), what, &rec.pattern, err)) < 0)
                return r;
        if ((r = get_ranged_int(j, "light", -1, INT32_MAX, &v, what, err)) < 0)
                return r;
        rec.light = (int) v;
        if ((r = get_ranged_int(j, "exposure_index", 0, INT32_MAX, &v, what, err)) < 0)
                return r;
        rec.exposure_index = (int) v;
        if ((r = imp_json_get_double(j, "exposure_us", true, &rec.exposure_us, what, err)) < 0 ||
            (r = imp_json_get_double(j, "gain_db", true, &rec.gain_db, what, err)) < 0)
                return r;
        if (!(rec.exposure_us >= 0 && rec.exposure_us < 1e12))
                return imp_error_set(err, -EINVAL, "%s: exposure_us: expected a number >= 0, got %g",
                                     what, rec.exposure_us);
        if (!(rec.gain_db > -1e3 && rec.gain_db < 1e3))
                return imp_error_set(err, -EINVAL, "%s: gain_db: expected a finite gain, got %g", what,
                                     rec.gain_db);
        if ((r = imp_json_get_int(j, "t_light_on_ns", true, &rec.t_light_on_ns, what, err)) < 0 ||
            (r = imp_json_get_int(j, "t_trigger_ns", true, &rec.t_trigger_ns, what, err)) < 0 ||
            (r = imp_json_get_int(j, "t_frame_ns", true, &rec.t_frame_ns, what, err)) < 0 ||
            (r = get_text(j, "file", rec.file, sizeof rec.file, what, err)) < 0 ||
            (r = get_ranged_int(j, "crc32", 0, UINT32_MAX, &v, what, err)) < 0)
                return r;
        rec.crc32 = (uint32_t) v;
        const json_t *st = json_object_get(j, "stage");
        if (st) {
                char w[600];
                snprintf(w, sizeof w, "%.500s: stage", what);
                if ((r = imp_json_get_doubles(st, "commanded_mm", true, 3, rec.stage_commanded_mm, w, err)) < 0 ||
                    (r = imp_json_get_doubles(st, "readback_mm", true, 3, rec.stage_readback_mm, w, err)) < 0)
                        return r;
                rec.has_stage = true;
        }
        *ret = rec;
        return 0;
}

/* ---- helpers ---- */

static char *path_in(const char *dir, const char *rel) {
        char *p;
        return asprintf(&p, "%s/%s", dir, rel) < 0 ? NULL : p;
}

/* "frames/000012.tiff": the file of manifest line i + 1 (thread-local buffer). */
static const char *frame_name(size_t i) {
        static __thread char buf[64];
        snprintf(buf, sizeof buf, FRAMES_DIR "/%06zu.tiff", i);
        return buf;
}

/* CRC-32 (zlib) and size of a whole file; fsyncs it too when `sync`. */
static int file_crc(const char *path, bool sync, uint32_t *ret_crc, long long *ret_bytes) {
        _cleanup_close_ int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0)
                return negative_errno();
        _cleanup_free_ unsigned char *buf = malloc(IO_CHUNK_BYTES);
        if (!buf)
                return -ENOMEM;
        uLong crc = crc32(0L, Z_NULL, 0);
        long long total = 0;
        for (;;) {
                ssize_t k = read(fd, buf, IO_CHUNK_BYTES);
                if (k < 0 && errno == EINTR)
                        continue;
                if (k < 0)
                        return negative_errno();
                if (k == 0)
                        break;
                crc = crc32(crc, buf, (uInt) k);
                total += k;
        }
        if (sync && fsync(fd) < 0)
                return negative_errno();
        *ret_crc = (uint32_t) crc;
        *ret_bytes = total;
        return 0;
}

static int fsync_dir(const char *dir) {
        _cleanup_close_ int fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (fd < 0)
                return negative_errno();
        return fsync(fd) < 0 ? negative_errno() : 0;
}

static int push_record(struct imp_captureset *cs, const struct imp_frame_record *rec,
                       long long size_bytes) {
        if (cs->n == cs->cap) {
                size_t cap = cs->cap ? cs->cap * 2 : 64;
                struct imp_frame_record *recs = realloc(cs->recs, cap * sizeof *recs);
                if (!recs)
                        return -ENOMEM;
                cs->recs = recs;
                long long *sizes = realloc(cs->sizes_bytes, cap * sizeof *sizes);
                if (!sizes)
                        return -ENOMEM;
                cs->sizes_bytes = sizes;
                cs->cap = cap;
        }
        cs->recs[cs->n] = *rec;
        cs->sizes_bytes[cs->n] = size_bytes;
        cs->n++;
        return 0;
}

static struct imp_captureset *cs_new(const char *dir) {
        struct imp_captureset *cs = calloc(1, sizeof *cs);
        if (!cs)
                return NULL;
        cs->manifest_fd = -1;
        cs->dir = strdup(dir);
        if (!cs->dir) {
                free(cs);
                return NULL;
        }
        return cs;
}

void imp_captureset_close(struct imp_captureset *cs) {
        if (!cs)
                return;
        if (cs->manifest_fd >= 0)
                close(cs->manifest_fd);        /* releases the flock */
        imp_rig_free(&cs->rig);
        free(cs->recs);
        free(cs->sizes_bytes);
        free(cs->dir);
        free(cs);
}
DEFINE_TRIVIAL_CLEANUP_FUNC(DIR *, closedir);

/* ---- create ---- */

static int dir_usable(const char *dir, struct imp_error *err) {
        _cleanup_(closedirp) DIR *d = opendir(dir);
        if (!d) {
                if (errno != ENOENT) {
                        int r = negative_errno();
                        return imp_error_set(err, r, "%s: %s", dir, strerror(-r));
                }
                int r = imp_mkdir_p(dir, 0755);
                if (r < 0)
                        return imp_error_set(err, r, "%s: cannot create: %s", dir, strerror(-r));
                return 0;
        }
        struct dirent *de;
        while ((de = readdir(d)))
                if (strcmp(de->d_name, ".") && strcmp(de->d_name, ".."))
                        return imp_error_set(err, -EEXIST, "%s: exists and is not empty (found %s)",
                                             dir, de->d_name);
        return 0;
}

/* The plan file's bytes (the set keeps a byte copy). */
static int read_plan(const char *plan_path, char **ret, size_t *ret_size, struct imp_error *err) {
        _cleanup_fclose_ FILE *f = fopen(plan_path, "re");
        if (!f) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", plan_path, strerror(-r));
        }
        _cleanup_free_ char *buf = NULL;
        size_t size = 0;
        _cleanup_fclose_ FILE *mem = open_memstream(&buf, &size);
        if (!mem)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", plan_path);
        char chunk[4096];
        size_t k;
        while ((k = fread(chunk, 1, sizeof chunk, f)) > 0)
                fwrite(chunk, 1, k, mem);
        if (ferror(f))
                return imp_error_set(err, -EIO, "%s: read error", plan_path);
        fclose(mem);
        mem = NULL;
        *ret = TAKE_PTR(buf);
        *ret_size = size;
        return 0;
}

static int create_empty(const char *dir, const char *name, int flags, int *ret_fd,
                        struct imp_error *err) {
        _cleanup_free_ char *p = path_in(dir, name);
        if (!p)
                return imp_error_set(err, -ENOMEM, "out of memory");
        int fd = open(p, O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC | flags, 0644);
        if (fd < 0 || fsync(fd) < 0) {
                int r = negative_errno();
                if (fd >= 0)
                        close(fd);
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        }
        if (ret_fd)
                *ret_fd = fd;
        else
                close(fd);
        return 0;
}

int imp_captureset_create(const char *dir, const struct imp_rig *rig, const char *plan_path,
                          struct imp_captureset **ret, struct imp_error *err) {
        _cleanup_free_ char *text = NULL;
        size_t size = 0;
        if (plan_path) {
                int r = read_plan(plan_path, &text, &size, err);
                if (r < 0)
                        return r;
        }
        return imp_captureset_create_with_plan(dir, rig, text, size, ret, err);
}

int imp_captureset_create_with_plan(const char *dir, const struct imp_rig *rig, const char *plan_text,
                                    size_t plan_size, struct imp_captureset **ret, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = cs_new(dir);
        if (!cs)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", dir);
        int r = dir_usable(dir, err);
        if (r < 0)
                return r;
        _cleanup_free_ char *frames = path_in(dir, FRAMES_DIR);
        _cleanup_free_ char *rig_path = path_in(dir, "rig.json");
        _cleanup_free_ char *plan_dst = path_in(dir, "plan.cfg");
        _cleanup_free_ char *set_path = path_in(dir, "set.json");
        if (!frames || !rig_path || !plan_dst || !set_path)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", dir);
        if (mkdir(frames, 0755) < 0) {
                r = negative_errno();
                return imp_error_set(err, r, "%s: %s", frames, strerror(-r));
        }
        if ((r = imp_rig_save(rig_path, rig, err)) < 0)
                return r;
        if (plan_text && (r = imp_file_write_atomic(plan_dst, plan_text, plan_size, err)) < 0)
                return r;
        if ((r = create_empty(dir, MANIFEST, O_APPEND, &cs->manifest_fd, err)) < 0 ||
            (r = create_empty(dir, "session.log", 0, NULL, err)) < 0)
                return r;
        if (flock(cs->manifest_fd, LOCK_EX | LOCK_NB) < 0) {
                r = negative_errno();
                return imp_error_set(err, r, "%s: cannot lock the manifest: %s", dir, strerror(-r));
        }
        /* set.json last: a directory without it is an interrupted create, not a set. */
        char created[32];
        time_t now = time(NULL);
        struct tm tm;
        strftime(created, sizeof created, "%Y-%m-%dT%H:%M:%SZ", gmtime_r(&now, &tm));
        _cleanup_json_ json_t *set = json_pack("{s:s, s:i, s:s}", "format", SET_FORMAT,
                                               "version", SET_VERSION, "created", created);
        if (!set)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", dir);
        if ((r = imp_json_save_atomic(set_path, set, err)) < 0)
                return r;
        if ((r = imp_rig_copy(rig, &cs->rig)) < 0)
                return imp_error_set(err, r, "%s: out of memory", dir);
        *ret = TAKE_PTR(cs);
        return 0;
}

/* ---- open ---- */

static int check_set_json(const char *dir, struct imp_error *err) {
        _cleanup_free_ char *p = path_in(dir, "set.json");
        if (!p)
                return imp_error_set(err, -ENOMEM, "out of memory");
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(p, &j, err);
        if (r == -ENOENT)
                return imp_error_set(err, -ENOENT, "%s: not a capture set (no set.json)", dir);
        if (r < 0)
                return r;
        const char *format;
        long long version;
        if ((r = imp_json_get_string(j, "format", true, &format, p, err)) < 0 ||
            (r = imp_json_get_int(j, "version", true, &version, p, err)) < 0)
                return r;
        if (strcmp(format, SET_FORMAT))
                return imp_error_set(err, -EINVAL, "%s: format: expected \"%s\", got \"%s\"", p,
                                     SET_FORMAT, format);
        if (version != SET_VERSION)
                return imp_error_set(err, -EPROTONOSUPPORT, "%s: version %lld is not supported "
                                     "(this build reads %d)", p, version, SET_VERSION);
        return 0;
}

static int read_fd_all(int fd, char **ret, size_t *ret_size) {
        struct stat st;
        if (fstat(fd, &st) < 0)
                return negative_errno();
        size_t cap = (size_t) st.st_size + 1, n = 0;
        char *buf = malloc(cap);
        if (!buf)
                return -ENOMEM;
        for (;;) {
                if (n + 1 >= cap) {
                        char *nb = realloc(buf, cap * 2);
                        if (!nb) {
                                free(buf);
                                return -ENOMEM;
                        }
                        buf = nb;
                        cap *= 2;
                }
                ssize_t k = pread(fd, buf + n, cap - 1 - n, (off_t) n);
                if (k < 0 && errno == EINTR)
                        continue;
                if (k < 0) {
                        int r = negative_errno();
                        free(buf);
                        return r;
                }
                if (k == 0)
                        break;
                n += (size_t) k;
        }
        buf[n] = 0;
        *ret = buf;
        *ret_size = n;
        return 0;
}

/* A record's file must be a plain name inside frames/: a set from elsewhere must not make
 * a worker read (or open() delete) anything outside it. */
static bool frame_name_ok(const char *file) {
        const char *name = file + strlen(FRAMES_DIR "/");
        return strncmp(file, FRAMES_DIR "/", strlen(FRAMES_DIR "/")) == 0 && name[0] &&
               !strchr(name, '/') && strcmp(name, ".") && strcmp(name, "..");
}

/* Parses one manifest line into a record and its file size. */
static int parse_line(const char *dir, const char *line, size_t len, size_t lineno,
                      struct imp_frame_record *ret, long long *ret_bytes, struct imp_error *err) {
        char what[512];
        snprintf(what, sizeof what, "%s/" MANIFEST ":%zu", dir, lineno);
        json_error_t je;
        _cleanup_json_ json_t *j = json_loadb(line, len, JSON_REJECT_DUPLICATES, &je);
        if (!j)
                return imp_error_set(err, -EBADMSG, "%s:%d: %s", what, je.column, je.text);
        struct imp_frame_record rec;
        long long bytes = 0;
        /* Any defect of a manifest line is damage to the set: -EBADMSG, message kept. */
        if (imp_frame_record_from_json(j, what, &rec, err) < 0 ||
            imp_json_get_int(j, "size_bytes", true, &bytes, what, err) < 0) {
                if (err)
                        err->code = -EBADMSG;
                return -EBADMSG;
        }
        if (!frame_name_ok(rec.file))
                return imp_error_set(err, -EBADMSG, "%s: file: expected \"frames/NAME\", got \"%s\"",
                                     what, rec.file);
        *ret = rec;
        *ret_bytes = bytes;
        return 0;
}

/* What follows the last good manifest line: nothing, or a torn / unreadable last line
 * (what a crash or a power loss can leave). */
struct manifest_tail {
        bool torn;
        size_t lineno;
        char why[600];
};

static int read_manifest(struct imp_captureset *cs, struct manifest_tail *tail, struct imp_error *err) {
        _cleanup_free_ char *buf = NULL;
        size_t size = 0;
        int r = read_fd_all(cs->manifest_fd, &buf, &size);
        if (r < 0)
                return imp_error_set(err, r, "%s/" MANIFEST ": %s", cs->dir, strerror(-r));
        size_t pos = 0, lineno = 0;
        *tail = (struct manifest_tail) { 0 };
        while (pos < size) {
                char *nl = memchr(buf + pos, '\n', size - pos);
                size_t end = nl ? (size_t) (nl - buf) : size;
                lineno++;
                if (!nl) {
                        /* the crash came in the middle of the last append */
                        *tail = (struct manifest_tail) { .torn = true, .lineno = lineno };
                        snprintf(tail->why, sizeof tail->why, "incomplete (no end of line)");
                        break;
                }
                struct imp_frame_record rec;
                long long bytes = 0;
                struct imp_error line_err = {};
                r = parse_line(cs->dir, buf + pos, end - pos, lineno, &rec, &bytes, &line_err);
                /* A well-formed record naming another line's frame is damage (a flipped bit,
                 * swapped lines), never a crash: refused even on the last line. */
                if (r == 0 && strcmp(rec.file, frame_name(lineno - 1)))
                        return imp_error_set(err, -EBADMSG, "%s/" MANIFEST ":%zu: file: expected \"%s\" (frames "
                                             "are named after their manifest line), got \"%s\"", cs->dir, lineno,
                                             frame_name(lineno - 1), rec.file);
                if (r < 0) {
                        /* A complete but unreadable *last* line is what a power loss can leave
                         * (the size grew, the data did not reach the disk). In the middle it is
                         * damage that we must not paper over. */
                        if (end + 1 == size) {
                                *tail = (struct manifest_tail) { .torn = true, .lineno = lineno };
                                snprintf(tail->why, sizeof tail->why, "unreadable (%.560s)", line_err.msg);
                                break;
                        }
                        if (err)
                                *err = line_err;
                        return r;
                }
                if ((r = push_record(cs, &rec, bytes)) < 0)
                        return imp_error_set(err, r, "%s: out of memory", cs->dir);
                pos = end + 1;
        }
        cs->manifest_bytes = (off_t) pos;
        return 0;
}

static int verify_frames_present(const struct imp_captureset *cs, struct imp_error *err) {
        for (size_t i = 0; i < cs->n; i++) {
                _cleanup_free_ char *p = path_in(cs->dir, cs->recs[i].file);
                if (!p)
                        return imp_error_set(err, -ENOMEM, "out of memory");
                struct stat st;
                if (stat(p, &st) < 0) {
                        int r = negative_errno();
                        return imp_error_set(err, r, "%s: listed in " MANIFEST ":%zu: %s", p, i + 1,
                                             strerror(-r));
                }
                if ((long long) st.st_size != cs->sizes_bytes[i])
                        return imp_error_set(err, -EBADMSG, "%s: %lld bytes, " MANIFEST ":%zu says %lld",
                                             p, (long long) st.st_size, i + 1, cs->sizes_bytes[i]);
        }
        return 0;
}

static int cmp_str(const void *a, const void *b) {
        return strcmp(*(const char *const *) a, *(const char *const *) b);
}

static bool ends_with(const char *s, const char *suffix) {
        size_t n = strlen(s), m = strlen(suffix);
        return n >= m && strcmp(s + n - m, suffix) == 0;
}

/* Frame files are "NNNNNN.tiff": only names of that shape are ours to delete. */
static bool looks_like_frame(const char *name) {
        size_t digits = strspn(name, "0123456789");
        return digits >= 6 && strcmp(name + digits, ".tiff") == 0;
}

/* Calls fn for each *.tmp in the set directory and in frames/, and each frame-shaped file
 * in frames/ that no manifest line lists: what a crash can leave, and nothing else (other
 * files are the operator's and are left alone). Stops at the first error fn returns. */
typedef int (*stray_fn)(const struct imp_captureset *cs, const char *rel, const char *reason, void *userdata,
                        struct imp_error *err);

static int for_each_stray(const struct imp_captureset *cs, stray_fn fn, void *userdata, struct imp_error *err) {
        _cleanup_free_ const char **names = malloc((cs->n + 1) * sizeof *names);
        if (!names)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t i = 0; i < cs->n; i++)
                names[i] = cs->recs[i].file + strlen(FRAMES_DIR "/");
        qsort(names, cs->n, sizeof *names, cmp_str);

        for (int pass = 0; pass < 2; pass++) {
                _cleanup_free_ char *d = pass ? path_in(cs->dir, FRAMES_DIR) : strdup(cs->dir);
                if (!d)
                        return imp_error_set(err, -ENOMEM, "out of memory");
                _cleanup_(closedirp) DIR *dh = opendir(d);
                if (!dh) {
                        int r = negative_errno();
                        return imp_error_set(err, r, "%s: %s", d, strerror(-r));
                }
                struct dirent *de;
                while ((de = readdir(dh))) {
                        const char *name = de->d_name, *reason = NULL;
                        if (ends_with(name, ".tmp"))
                                reason = "a temporary file (a write that a crash interrupted)";
                        else if (pass && looks_like_frame(name) &&
                                 !bsearch(&name, names, cs->n, sizeof *names, cmp_str))
                                reason = "a frame file no manifest line lists (a crash between storing the "
                                         "frame and recording it, or a damaged manifest)";
                        if (!reason)
                                continue;
                        char rel[300];
                        snprintf(rel, sizeof rel, "%s%s", pass ? FRAMES_DIR "/" : "", name);
                        int r = fn(cs, rel, reason, userdata, err);
                        if (r < 0)
                                return r;
                }
        }
        return 0;
}

/* Opens the manifest for appending and takes the writer's lock; when another process
 * holds it (a daemon still capturing) or the set is read-only, opens for reading only. */
static int open_manifest(struct imp_captureset *cs, struct imp_error *err) {
        _cleanup_free_ char *p = path_in(cs->dir, MANIFEST);
        if (!p)
                return imp_error_set(err, -ENOMEM, "out of memory");
        cs->manifest_fd = open(p, O_RDWR | O_APPEND | O_CLOEXEC);
        if (cs->manifest_fd < 0 && (errno == EACCES || errno == EROFS || errno == EPERM)) {
                cs->read_only = negative_errno();
                cs->manifest_fd = open(p, O_RDONLY | O_CLOEXEC);
        }
        if (cs->manifest_fd < 0) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        }
        if (!cs->read_only && flock(cs->manifest_fd, LOCK_EX | LOCK_NB) < 0) {
                if (errno != EWOULDBLOCK) {
                        int r = negative_errno();
                        return imp_error_set(err, r, "%s: cannot lock: %s", p, strerror(-r));
                }
                cs->read_only = -EBUSY;
        }
        return 0;
}

/* set.json, rig.json and the manifest read into cs; the manifest open as open_manifest()
 * decides (appending when this process got the writer's lock). */
static int load_set(struct imp_captureset *cs, struct manifest_tail *tail, struct imp_error *err) {
        int r = check_set_json(cs->dir, err);
        if (r < 0)
                return r;
        _cleanup_free_ char *rig_path = path_in(cs->dir, "rig.json");
        if (!rig_path)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        if ((r = imp_rig_load(rig_path, &cs->rig, err)) < 0 || (r = open_manifest(cs, err)) < 0)
                return r;
        return read_manifest(cs, tail, err);
}

int imp_captureset_open(const char *dir, struct imp_captureset **ret, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = cs_new(dir);
        if (!cs)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", dir);
        struct manifest_tail tail;
        int r = load_set(cs, &tail, err);
        if (r < 0)
                return r;
        /* A torn tail while another process holds the writer's lock is its append in
         * progress: the view ends before it. Without a writer it is what a crash left, and
         * only an explicit repair (or the daemon's resume) may take it away. */
        if (tail.torn && cs->read_only != -EBUSY)
                return imp_error_set(err, -EBADMSG, "%s/" MANIFEST ":%zu: the last line is %s: a capture "
                                     "that crashed or lost power? The set is left as it is; `impasto repair "
                                     "%s` moves the line and its frame to quarantine/ (or resume the session)",
                                     dir, tail.lineno, tail.why, dir);
        if ((r = verify_frames_present(cs, err)) < 0)
                return r;
        *ret = TAKE_PTR(cs);
        return 0;
}

/* ---- repair ---- */

/* A free name for `base` in quarantine/ ("000012.tiff", then "000012.tiff.1", …). */
static int quarantine_name(const char *qdir, const char *base, char *ret, size_t size) {
        for (int k = 0; k < 1000; k++) {
                if (k == 0)
                        snprintf(ret, size, "%s/%s", qdir, base);
                else
                        snprintf(ret, size, "%s/%s.%d", qdir, base, k);
                if (access(ret, F_OK) < 0 && errno == ENOENT)
                        return 0;
        }
        return -EEXIST;
}

struct repair {
        bool dry_run;
        json_t *report;
        char *qdir;
};

static int quarantine_dir(const struct imp_captureset *cs, struct repair *rp, struct imp_error *err) {
        if (rp->qdir)
                return 0;
        rp->qdir = path_in(cs->dir, IMP_CAPTURESET_QUARANTINE);
        if (!rp->qdir)
                return imp_error_set(err, -ENOMEM, "out of memory");
        if (mkdir(rp->qdir, 0755) < 0 && errno != EEXIST) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", rp->qdir, strerror(-r));
        }
        return 0;
}

static int report_item(struct repair *rp, const char *rel, const char *reason, const char *moved_to) {
        json_t *item = json_pack("{s:s, s:s, s:s*}", "path", rel, "reason", reason, "moved_to", moved_to);
        return item && json_array_append_new(rp->report, item) == 0 ? 0 : -ENOMEM;
}

/* Moves one stray into quarantine/ (renamed, never copied or deleted), fsyncing both. */
static int move_stray(const struct imp_captureset *cs, const char *rel, const char *reason, void *userdata,
                      struct imp_error *err) {
        struct repair *rp = userdata;
        if (rp->dry_run)
                return report_item(rp, rel, reason, NULL) < 0 ? imp_error_set(err, -ENOMEM, "out of memory") : 0;
        int r = quarantine_dir(cs, rp, err);
        if (r < 0)
                return r;
        const char *base = strrchr(rel, '/') ? strrchr(rel, '/') + 1 : rel;
        char dst[PATH_MAX];
        _cleanup_free_ char *src = path_in(cs->dir, rel);
        if (!src)
                return imp_error_set(err, -ENOMEM, "out of memory");
        if ((r = quarantine_name(rp->qdir, base, dst, sizeof dst)) < 0 || rename(src, dst) < 0) {
                r = r < 0 ? r : negative_errno();
                return imp_error_set(err, r, "%s: cannot move to %s: %s", src, rp->qdir, strerror(-r));
        }
        if ((r = fsync_dir(rp->qdir)) < 0)
                return imp_error_set(err, r, "%s: fsync: %s", rp->qdir, strerror(-r));
        _cleanup_free_ char *parent = strdup(src);
        if (parent && strrchr(parent, '/'))
                *strrchr(parent, '/') = 0;
        if (parent && (r = fsync_dir(parent)) < 0)
                return imp_error_set(err, r, "%s: fsync: %s", parent, strerror(-r));
        return report_item(rp, rel, reason, dst + strlen(cs->dir) + 1) < 0
                       ? imp_error_set(err, -ENOMEM, "out of memory") : 0;
}

/* Saves the torn tail's bytes in quarantine/ and cuts the manifest back to its last good
 * line: the bytes are kept, the manifest is whole again. */
static int move_tail(struct imp_captureset *cs, const struct manifest_tail *tail, struct repair *rp,
                     struct imp_error *err) {
        char rel[64], reason[700];   /* why: 600 */
        snprintf(rel, sizeof rel, MANIFEST ":%zu", tail->lineno);
        snprintf(reason, sizeof reason, "the last manifest line is %s", tail->why);
        if (rp->dry_run)
                return report_item(rp, rel, reason, NULL) < 0 ? imp_error_set(err, -ENOMEM, "out of memory") : 0;
        int r = quarantine_dir(cs, rp, err);
        if (r < 0)
                return r;
        _cleanup_free_ char *buf = NULL;
        size_t size = 0;
        if ((r = read_fd_all(cs->manifest_fd, &buf, &size)) < 0)
                return imp_error_set(err, r, "%s/" MANIFEST ": %s", cs->dir, strerror(-r));
        char dst[PATH_MAX];
        if ((r = quarantine_name(rp->qdir, "manifest-tail.jsonl", dst, sizeof dst)) < 0)
                return imp_error_set(err, r, "%s: %s", rp->qdir, strerror(-r));
        if ((r = imp_file_write_atomic(dst, buf + cs->manifest_bytes, size - (size_t) cs->manifest_bytes, err)) < 0)
                return r;
        if (ftruncate(cs->manifest_fd, cs->manifest_bytes) < 0 || fsync(cs->manifest_fd) < 0) {
                r = negative_errno();
                return imp_error_set(err, r, "%s/" MANIFEST ": cannot cut the torn line: %s", cs->dir, strerror(-r));
        }
        return report_item(rp, rel, reason, dst + strlen(cs->dir) + 1) < 0
                       ? imp_error_set(err, -ENOMEM, "out of memory") : 0;
}

int imp_captureset_repair(const char *dir, bool dry_run, json_t **ret_report, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = cs_new(dir);
        if (!cs)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", dir);
        struct manifest_tail tail;
        int r = load_set(cs, &tail, err);
        if (r < 0)
                return r;
        if (cs->read_only)
                return imp_error_set(err, cs->read_only, "%s: cannot repair: %s", dir,
                                     cs->read_only == -EBUSY ? "another process is writing it"
                                                             : strerror(-cs->read_only));
        /* A listed frame missing or resized is damage, not a crash: nothing is moved. */
        if ((r = verify_frames_present(cs, err)) < 0)
                return r;
        struct repair rp = { .dry_run = dry_run, .report = json_array() };
        if (!rp.report)
                return imp_error_set(err, -ENOMEM, "out of memory");
        if (tail.torn)
                r = move_tail(cs, &tail, &rp, err);
        if (r >= 0)
                r = for_each_stray(cs, move_stray, &rp, err);
        free(rp.qdir);
        if (r < 0) {
                json_decref(rp.report);
                return r;
        }
        *ret_report = rp.report;
        return (int) json_array_size(rp.report);
}

/* ---- append ---- */

int imp_captureset_add_frame(struct imp_captureset *cs, struct imp_frame_record *rec,
                             const struct imp_image *frame, struct imp_error *err) {
        if (cs->read_only)
                return imp_error_set(err, cs->read_only, "%s: opened for reading only (%s)", cs->dir,
                                     cs->read_only == -EBUSY ? "another process is writing it"
                                                             : strerror(-cs->read_only));
        if (frame->type != IMP_PIX_U16 || frame->channels < 1 || frame->channels > 4)
                return imp_error_set(err, -EINVAL, "%s: frames are 16-bit with 1 to 4 channels, got "
                                     "%s with %d", cs->dir, imp_pixel_type_name(frame->type),
                                     frame->channels);
        struct imp_frame_record r = *rec;
        snprintf(r.file, sizeof r.file, FRAMES_DIR "/%06zu.tiff", cs->n);
        r.crc32 = 0;
        _cleanup_free_ char *path = path_in(cs->dir, r.file);
        _cleanup_free_ char *tmp = NULL;
        if (!path || asprintf(&tmp, "%s.tmp", path) < 0)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);

        /* The TIFF carries its own record (without the checksum of itself). */
        _cleanup_json_ json_t *j = imp_frame_record_to_json(&r);
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        json_object_del(j, "crc32");
        _cleanup_free_ char *desc = json_dumps(j, JSON_COMPACT | JSON_REAL_PRECISION(17));
        if (!desc)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        /* Whatever is there is not part of the set, but it is not ours to overwrite either. */
        if (access(path, F_OK) == 0 || access(tmp, F_OK) == 0)
                return imp_error_set(err, -EEXIST, "%s (or its .tmp) exists but is not in the manifest: "
                                     "`impasto repair %s` moves it to quarantine/", path, cs->dir);
        int ret = imp_tiff_write_fast(tmp, frame, desc, err);
        if (ret < 0)
                return ret;
        long long bytes = 0;
        ret = file_crc(tmp, true, &r.crc32, &bytes);
        if (ret == 0 && renameat2(AT_FDCWD, tmp, AT_FDCWD, path, RENAME_NOREPLACE) < 0)
                ret = negative_errno();
        if (ret < 0) {
                unlink(tmp);
                return imp_error_set(err, ret, "%s: %s", tmp, strerror(-ret));
        }
        _cleanup_free_ char *frames = path_in(cs->dir, FRAMES_DIR);
        if (!frames)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        if ((ret = fsync_dir(frames)) < 0)
                return imp_error_set(err, ret, "%s: fsync: %s", frames, strerror(-ret));

        /* The frame is durable; now the line that makes it part of the set. */
        json_decref(j);
        j = imp_frame_record_to_json(&r);
        if (!j || json_object_set_new(j, "size_bytes", json_integer(bytes)) < 0)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        _cleanup_free_ char *line = json_dumps(j, JSON_COMPACT | JSON_REAL_PRECISION(17));
        if (!line)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        size_t len = strlen(line);
        if (len + 1 > MANIFEST_LINE_MAX_BYTES)
                return imp_error_set(err, -E2BIG, "%s: manifest line too long", cs->dir);
        line[len] = '\n';   /* over the NUL: one write() of the whole line */
        ret = imp_write_all(cs->manifest_fd, line, len + 1);
        line[len] = 0;
        if (ret == 0 && fsync(cs->manifest_fd) < 0)
                ret = negative_errno();
        if (ret < 0) {
                /* Take back a partial line so that the next append starts on a clean line. */
                if (ftruncate(cs->manifest_fd, cs->manifest_bytes) == 0)
                        (void) fsync(cs->manifest_fd);
                return imp_error_set(err, ret, "%s/" MANIFEST ": %s", cs->dir, strerror(-ret));
        }
        if ((ret = push_record(cs, &r, bytes)) < 0)
                return imp_error_set(err, ret, "%s: out of memory", cs->dir);
        cs->manifest_bytes += (off_t) (len + 1);
        memcpy(rec->file, r.file, sizeof rec->file);
        rec->crc32 = r.crc32;
        return 0;
}

/* ---- reading ---- */

size_t imp_captureset_count(const struct imp_captureset *cs) { return cs->n; }

const struct imp_frame_record *imp_captureset_record(const struct imp_captureset *cs, size_t i) {
        return i < cs->n ? &cs->recs[i] : NULL;
}

const struct imp_rig *imp_captureset_rig(const struct imp_captureset *cs) { return &cs->rig; }

const char *imp_captureset_dir(const struct imp_captureset *cs) { return cs->dir; }

/* The first field in which two records differ ("light", "pattern.bit", …), or NULL. */
static const char *record_diff(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        const struct imp_pattern *p = &a->pattern, *q = &b->pattern;
        return a->seq != b->seq ? "seq" : strcmp(a->step, b->step) ? "step" : strcmp(a->camera, b->camera) ? "camera"
               : a->tile != b->tile ? "tile" : p->kind != q->kind ? "pattern.kind" : p->axis != q->axis ? "pattern.axis"
               : p->bit != q->bit ? "pattern.bit" : p->nbits != q->nbits ? "pattern.nbits"
               : p->inverse != q->inverse ? "pattern.inverse" : p->period_px != q->period_px ? "pattern.period_px"
               : p->step != q->step ? "pattern.step" : p->steps != q->steps ? "pattern.steps"
               : a->light != b->light ? "light" : a->exposure_index != b->exposure_index ? "exposure_index"
               : a->exposure_us != b->exposure_us ? "exposure_us" : a->gain_db != b->gain_db ? "gain_db"
               : a->t_light_on_ns != b->t_light_on_ns ? "t_light_on_ns" : a->t_trigger_ns != b->t_trigger_ns ? "t_trigger_ns"
               : a->t_frame_ns != b->t_frame_ns ? "t_frame_ns" : strcmp(a->file, b->file) ? "file"
               : a->has_stage != b->has_stage || memcmp(a->stage_commanded_mm, b->stage_commanded_mm, sizeof a->stage_commanded_mm) ||
                 memcmp(a->stage_readback_mm, b->stage_readback_mm, sizeof a->stage_readback_mm) ? "stage" : NULL;
}

/* The record each frame carries in its ImageDescription must be the manifest's line, field
 * for field: a flipped bit in the manifest (`"light":3` → 7) or two frames swapped (with
 * their checksums) would otherwise give a wrong copy without a word. */
static int check_embedded(const struct imp_captureset *cs, size_t i, const char *path, const char *desc,
                          struct imp_error *err) {
        const struct imp_frame_record *rec = &cs->recs[i];
        json_error_t je;
        _cleanup_json_ json_t *j = desc ? json_loads(desc, JSON_REJECT_DUPLICATES, &je) : NULL;
        if (!j || !json_is_object(j))
                return imp_error_set(err, -EBADMSG, "%s: no frame record in the TIFF's ImageDescription: the frame "
                                     "cannot be checked against " MANIFEST ":%zu", path, i + 1);
        json_object_set_new(j, "crc32", json_integer(rec->crc32));   /* a file cannot hold its own */
        struct imp_frame_record emb;
        char what[PATH_MAX + 40];
        snprintf(what, sizeof what, "%s: embedded record", path);
        int r = imp_frame_record_from_json(j, what, &emb, err);
        if (r < 0)
                return r;
        const char *field = record_diff(rec, &emb);
        if (!field)
                return 0;
        _cleanup_json_ json_t *mj = imp_frame_record_to_json(rec);
        _cleanup_json_ json_t *ej = imp_frame_record_to_json(&emb);
        const char *key = strncmp(field, "pattern.", 8) ? field : "pattern";
        _cleanup_free_ char *mv = json_dumps(json_object_get(mj, key), JSON_ENCODE_ANY | JSON_COMPACT);
        _cleanup_free_ char *ev = json_dumps(json_object_get(ej, key), JSON_ENCODE_ANY | JSON_COMPACT);
        return imp_error_set(err, -EBADMSG, "%s: %s: " MANIFEST ":%zu says %s, the frame's embedded record says %s: "
                             "the manifest or the frame is damaged, or frames were swapped", path, field, i + 1,
                             mv ? mv : "?", ev ? ev : "?");
}

int imp_captureset_load_frame(const struct imp_captureset *cs, size_t i, struct imp_image **ret,
                              struct imp_error *err) {
        struct imp_image *img = NULL;
        int r = imp_captureset_load_frame_reuse(cs, i, &img, err);
        if (r < 0) {
                imp_image_free(img);
                return r;
        }
        *ret = img;
        return 0;
}

int imp_captureset_load_frame_reuse(const struct imp_captureset *cs, size_t i, struct imp_image **io,
                                    struct imp_error *err) {
        if (i >= cs->n)
                return imp_error_set(err, -ERANGE, "%s: frame %zu of %zu", cs->dir, i, cs->n);
        const struct imp_frame_record *rec = &cs->recs[i];
        _cleanup_free_ char *path = path_in(cs->dir, rec->file);
        if (!path)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", cs->dir);
        uint32_t crc = 0;
        long long bytes = 0;
        int r = file_crc(path, false, &crc, &bytes);
        if (r < 0)
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        if (crc != rec->crc32)
                return imp_error_set(err, -EBADMSG, "%s: checksum mismatch (manifest says %08x, file "
                                     "has %08x): the frame is damaged", path, rec->crc32, crc);
        _cleanup_free_ char *desc = NULL;
        if ((r = imp_tiff_read_reuse(path, io, &desc, err)) < 0 ||
            (r = check_embedded(cs, i, path, desc, err)) < 0)
                return r;
        const struct imp_image *img = *io;
        if (img->type != IMP_PIX_U16)
                return imp_error_set(err, -EBADMSG, "%s: expected a 16-bit frame, got %s", path,
                                     imp_pixel_type_name(img->type));
        /* the stages index frames with the camera's model size: a frame of another size
         * (or rig.json's model.width/height changed) would be read out of bounds */
        const struct imp_rig_camera *cam = NULL;
        for (int c = 0; c < cs->rig.n_cameras; c++)
                if (!strcmp(cs->rig.cameras[c].name, rec->camera))
                        cam = &cs->rig.cameras[c];
        if (!cam)
                return imp_error_set(err, -EBADMSG, "%s: camera: " MANIFEST ":%zu names camera \"%s\", which "
                                     "rig.json does not have", path, i + 1, rec->camera);
        if (img->width != cam->model.width || img->height != cam->model.height)
                return imp_error_set(err, -EBADMSG, "%s: the frame is %d × %d pixels, rig.json says camera %s "
                                     "(model.width, model.height) is %d × %d: the frame or rig.json is damaged",
                                     path, img->width, img->height, cam->name, cam->model.width,
                                     cam->model.height);
        return 0;
}

/* ---- completeness against the plan ---- */

/* The set's plan.cfg expanded against its rig; *ret NULL when the set has no plan. Read as
 * text: a set's plan may not @include (the set may come from anywhere). */
static int load_own_plan(const struct imp_captureset *cs, struct imp_plan **ret, struct imp_error *err) {
        _cleanup_free_ char *p = path_in(cs->dir, "plan.cfg");
        if (!p)
                return imp_error_set(err, -ENOMEM, "out of memory");
        *ret = NULL;
        _cleanup_close_ int fd = open(p, O_RDONLY | O_CLOEXEC | O_NONBLOCK | O_NOFOLLOW);
        if (fd < 0 && errno == ENOENT)
                return 0;
        if (fd < 0) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        }
        struct stat st;
        if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode) || st.st_size > (1 << 20))
                return imp_error_set(err, -EBADMSG, "%s: not a plan file (a regular file of at most 1 MiB)", p);
        _cleanup_free_ char *text = NULL;
        size_t size = 0;
        int r = read_fd_all(fd, &text, &size);
        if (r < 0)
                return imp_error_set(err, r, "%s: %s", p, strerror(-r));
        return imp_plan_load_string(text, p, &cs->rig, ret, err);
}

int imp_captureset_load_plan(const struct imp_captureset *cs, struct imp_plan **ret, struct imp_error *err) {
        return load_own_plan(cs, ret, err);
}

/* The record of `rec` must be the plan's frame of the same seq (what was captured is what
 * the plan asked for): the first field that differs, or NULL. */
static const char *plan_diff(const struct imp_frame_record *rec, const struct imp_frame_record *want) {
        struct imp_frame_record a = *rec;
        /* what the plan cannot know */
        a.t_light_on_ns = want->t_light_on_ns;
        a.t_trigger_ns = want->t_trigger_ns;
        a.t_frame_ns = want->t_frame_ns;
        memcpy(a.file, want->file, sizeof a.file);
        a.crc32 = want->crc32;
        a.has_stage = want->has_stage;       /* the gantry's pose is the daemon's, not the plan's */
        memcpy(a.stage_commanded_mm, want->stage_commanded_mm, sizeof a.stage_commanded_mm);
        memcpy(a.stage_readback_mm, want->stage_readback_mm, sizeof a.stage_readback_mm);
        return record_diff(&a, want);
}

static json_t *missing_step(json_t *steps, const char *step) {
        json_t *o = json_object_get(steps, step);
        if (!o) {
                o = json_pack("{s:i, s:i, s:[]}", "planned", 0, "missing", 0, "lights");
                json_object_set_new(steps, step, o);
        }
        return o;
}

static void count_in(json_t *o, const char *key) {
        json_object_set_new(o, key, json_integer(json_integer_value(json_object_get(o, key)) + 1));
}

/* "dome: 11 of 12 frames (lights 1, 2, 3, …); structured-light: …" */
static void describe_missing(json_t *steps, char *buf, size_t size) {
        const char *step;
        json_t *o;
        buf[0] = 0;
        json_object_foreach(steps, step, o) {
                long long miss = json_integer_value(json_object_get(o, "missing"));
                if (!miss)
                        continue;
                size_t n = strlen(buf);
                snprintf(buf + n, size - n, "%s%s: %lld of %lld frames", n ? "; " : "", step, miss,
                         json_integer_value(json_object_get(o, "planned")));
                json_t *lights = json_object_get(o, "lights");
                for (size_t i = 0; i < json_array_size(lights) && i < 8; i++) {
                        n = strlen(buf);
                        snprintf(buf + n, size - n, "%s%lld", i ? ", " : " (lights ",
                                 json_integer_value(json_array_get(lights, i)));
                }
                n = strlen(buf);
                if (json_array_size(lights))
                        snprintf(buf + n, size - n, "%s)", json_array_size(lights) > 8 ? ", …" : "");
                n = strlen(buf);
                if (!strcmp(step, "dome") && miss == json_integer_value(json_object_get(o, "planned")))
                        snprintf(buf + n, size - n, ": no photometric frame, so no BTF possible");
        }
}

int imp_captureset_check_complete(const struct imp_captureset *cs, json_t **ret_missing, struct imp_error *err) {
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        *ret_missing = NULL;
        int r = load_own_plan(cs, &plan, err);
        if (r < 0 || !plan)
                return r;
        size_t np = imp_plan_count(plan);
        _cleanup_free_ bool *have = calloc(np ? np : 1, sizeof *have);
        if (!have)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t i = 0; i < cs->n; i++) {
                const struct imp_frame_record *rec = &cs->recs[i];
                if (rec->seq < 0 || (size_t) rec->seq >= np)
                        return imp_error_set(err, -EBADMSG, "%s/" MANIFEST ":%zu: seq: %lld, but the set's plan has "
                                             "%zu frames", cs->dir, i + 1, rec->seq, np);
                const char *field = plan_diff(rec, imp_plan_frame(plan, (size_t) rec->seq));
                if (field)
                        return imp_error_set(err, -EBADMSG, "%s/" MANIFEST ":%zu (%s): %s: differs from frame %lld of "
                                             "the set's plan.cfg: the manifest is damaged", cs->dir, i + 1, rec->file,
                                             field, rec->seq);
                have[rec->seq] = true;
        }
        _cleanup_json_ json_t *steps = json_object();
        size_t missing = 0;
        for (size_t k = 0; steps && k < np; k++) {
                const struct imp_frame_record *f = imp_plan_frame(plan, k);
                json_t *o = missing_step(steps, f->step);
                count_in(o, "planned");
                if (have[k])
                        continue;
                missing++;
                count_in(o, "missing");
                json_t *lights = json_object_get(o, "lights");
                bool listed = f->light < 0;
                for (size_t i = 0; !listed && i < json_array_size(lights); i++)
                        listed = json_integer_value(json_array_get(lights, i)) == f->light;
                if (!listed)
                        json_array_append_new(lights, json_integer(f->light));
        }
        if (!steps)
                return imp_error_set(err, -ENOMEM, "out of memory");
        if (!missing)
                return 0;
        char what[1024];
        describe_missing(steps, what, sizeof what);
        *ret_missing = json_pack("{s:I, s:I, s:I, s:O}", "frames_planned", (json_int_t) np, "frames_present",
                                 (json_int_t) (np - missing), "frames_missing", (json_int_t) missing, "steps", steps);
        imp_error_set(err, -ENODATA, "%s: incomplete: %zu of the plan's %zu frames are missing (%s)", cs->dir, missing,
                      np, what);
        return 1;
}
