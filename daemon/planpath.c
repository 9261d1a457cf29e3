/* Plan paths named by clients (PROTOCOL §8). The daemon reads plans with its own rights, so a
 * path from the socket is confined: below the --plan-dir directories when any is configured,
 * a regular file of bounded size, and readable by the peer itself. A refused path is
 * `not_found` naming it, and nothing of its content reaches the client. */
#define _GNU_SOURCE 1
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>
#include "impastod.h"
#include "macro.h"

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

int plan_path_resolve(struct daemon *d, const struct daemon_peer *peer, const char *path, const char *field,
                      char ret[static PATH_MAX], struct imp_proto_error *perr) {
        char real[PATH_MAX];
        if (!path || !path[0] || !realpath(path, real))
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, ENOENT, field, "%s: no such plan file",
                                           path ? path : "");
        if (d->n_plan_dirs > 0) {
                bool ok = false;
                for (unsigned i = 0; i < d->n_plan_dirs && !ok; i++)
                        ok = below(real, d->plan_dirs[i]);
                if (!ok) {
                        char dirs[1024] = "";
                        for (unsigned i = 0; i < d->n_plan_dirs; i++)
                                snprintf(dirs + strlen(dirs), sizeof dirs - strlen(dirs), "%s%s", i ? ", " : "",
                                         d->plan_dirs[i]);
                        return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, EACCES, field,
                                                   "%s: not a plan of this daemon: plans are read only below %s",
                                                   path, dirs);
                }
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
