/* Plan paths named by clients (PROTOCOL §8). The daemon reads plans with its own rights, so a
 * path from the socket is confined: below the --plan-dir directories when any is configured,
 * a regular file of bounded size, and readable by the peer itself. A refused path is
 * `not_found` naming it, and nothing of its content reaches the client. The plan is then read
 * without blocking the event loop (plan_read) and parsed as text, which may not @include. */
#define _GNU_SOURCE 1
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <linux/openat2.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>
#include "impastod.h"
#include "macro.h"
#include "plan.h"

/* Would the peer get `bit` (4 read, 1 search) on this inode by its mode bits? */
static bool peer_may(const struct stat *st, const struct daemon_peer *peer, mode_t bit) {
        if (st->st_uid == peer->uid)
                return st->st_mode & (bit << 6);
        if (daemon_peer_in_group(peer, st->st_gid))     /* groups from SO_PEERGROUPS (server.c) */
                return st->st_mode & (bit << 3);
        return st->st_mode & bit;
}

/* Every directory from / to the file must be searchable by the peer, the file readable. */
static bool peer_can_read(const char *real, const struct daemon_peer *peer) {
        if (peer->uid == 0 || peer->uid == geteuid())
                return true;    /* the daemon grants it nothing it does not have */
        char prefix[PATH_MAX];
        struct stat st;
        for (const char *p = real; (p = strchr(p, '/')); p++) {
                size_t n = p == real ? 1 : (size_t) (p - real);
                memcpy(prefix, real, n);
                prefix[n] = 0;
                if (stat(prefix, &st) < 0 || !peer_may(&st, peer, 1))
                        return false;
        }
        return stat(real, &st) == 0 && peer_may(&st, peer, 4);
}

static bool below(const char *real, const char *dir) {
        char rdir[PATH_MAX];
        if (!realpath(dir, rdir))
                return false;
        size_t n = strlen(rdir);
        if (n == 1)
                return true;    /* "/" */
        return !strncmp(real, rdir, n) && real[n] == '/';
}

/* One answer for "outside the plan directories" and "does not resolve": a client must not
 * learn whether a file outside exists (a dangling symlink in a plan directory would tell). */
static int not_a_plan(struct daemon *d, const char *path, const char *field, struct imp_proto_error *perr) {
        char dirs[1024] = "";
        for (unsigned i = 0; i < d->n_plan_dirs; i++)
                snprintf(dirs + strlen(dirs), sizeof dirs - strlen(dirs), "%s%s", i ? ", " : "", d->plan_dirs[i]);
        return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, ENOENT, field,
                                   "%s: not a plan of this daemon: plans are read only below %s", path, dirs);
}

int plan_path_resolve(struct daemon *d, const struct daemon_peer *peer, const char *path, const char *field,
                      char ret[static PATH_MAX], struct imp_proto_error *perr) {
        char real[PATH_MAX];
        bool resolved = path && path[0] && realpath(path, real);
        if (!resolved && d->n_plan_dirs == 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, ENOENT, field, "%s: no such plan file",
                                           path ? path : "");
        if (d->n_plan_dirs > 0) {
                bool ok = false;
                for (unsigned i = 0; resolved && i < d->n_plan_dirs && !ok; i++)
                        ok = below(real, d->plan_dirs[i]);
                if (!ok)
                        return not_a_plan(d, path ? path : "", field, perr);
        }
        struct stat st;
        if (stat(real, &st) < 0 || !S_ISREG(st.st_mode))
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EACCES, field,
                                           "%s: not a regular file, so not a plan", path);
        if (st.st_size > DAEMON_PLAN_MAX_BYTES)
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EFBIG, field,
                                           "%s: %lld bytes, more than a plan's %d", path, (long long) st.st_size,
                                           DAEMON_PLAN_MAX_BYTES);
        if (peer && !peer_can_read(real, peer))
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EACCES, field,
                                           "%s: not readable by the client (uid %u), so not read for it", path,
                                           (unsigned) peer->uid);
        snprintf(ret, PATH_MAX, "%s", real);
        return 0;
}

int plan_path_builtin(struct daemon *d, const char *name, char ret[static PATH_MAX]) {
        for (unsigned i = 0; i < d->n_plan_dirs; i++) {
                char p[PATH_MAX + 256];
                snprintf(p, sizeof p, "%s/%s", d->plan_dirs[i], name);
                if (access(p, R_OK) == 0 && realpath(p, ret))
                        return 0;
        }
        return -ENOENT;
}

/* Opens a resolved plan path for reading: no symlink anywhere on the way (openat2; the path
 * is already resolved, so a symlink there is a swap since), O_NONBLOCK so that a FIFO or a
 * device swapped in cannot block the loop, O_NOCTTY. Falls back to O_NOFOLLOW before 5.6. */
static int open_plan(const char *real) {
        struct open_how how = { .flags = O_RDONLY | O_NONBLOCK | O_NOFOLLOW | O_CLOEXEC | O_NOCTTY,
                                .resolve = RESOLVE_NO_SYMLINKS | RESOLVE_NO_MAGICLINKS };
        int fd = (int) syscall(SYS_openat2, AT_FDCWD, real, &how, sizeof how);
        if (fd < 0 && (errno == ENOSYS || errno == EPERM))
                fd = open(real, (int) how.flags);
        return fd < 0 ? negative_errno() : fd;
}

int plan_read(const char *path, char **ret_text, struct imp_proto_error *perr) {
        _cleanup_close_ int fd = open_plan(path);
        if (fd < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, -fd, "args.plan", "%s: cannot open the plan: %s",
                                           path, strerror(-fd));
        struct stat st;
        if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode))
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EACCES, "args.plan",
                                           "%s: not a regular file, so not a plan", path);
        _cleanup_free_ char *buf = malloc(DAEMON_PLAN_MAX_BYTES + 2);
        if (!buf)
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
        size_t n = 0;
        while (n <= DAEMON_PLAN_MAX_BYTES) {
                ssize_t k = read(fd, buf + n, DAEMON_PLAN_MAX_BYTES + 1 - n);
                if (k < 0 && errno == EINTR)
                        continue;
                if (k < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, errno, "args.plan", "%s: %s", path,
                                                   strerror(errno));
                if (k == 0)
                        break;
                n += (size_t) k;
        }
        if (n > DAEMON_PLAN_MAX_BYTES)
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EFBIG, "args.plan",
                                           "%s: more than a plan's %d bytes", path, DAEMON_PLAN_MAX_BYTES);
        if (memchr(buf, 0, n))
                return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, EINVAL, "args.plan",
                                           "%s: a NUL byte: not a text file, so not a plan", path);
        buf[n] = 0;
        *ret_text = TAKE_PTR(buf);
        return 0;
}

int plan_load_text(struct daemon *d, const char *path, struct imp_plan **ret, char **ret_text,
                   struct imp_proto_error *perr) {
        if (!d->have_rig)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, ENODATA, NULL,
                                           "the rig has no calibration (rig.json) loaded");
        _cleanup_free_ char *text = NULL;
        int r = plan_read(path, &text, perr);
        if (r < 0)
                return r;
        struct imp_error e = { 0 };
        if ((r = imp_plan_load_string(text, path, &d->rig, ret, &e)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, -r, "args.plan", "%s", e.msg);
        if (ret_text)
                *ret_text = TAKE_PTR(text);
        return 0;
}
