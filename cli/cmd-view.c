/* `impasto view COPY_DIR [--port N] [--bind ADDR] [--cache DIR | --no-cache]`: serves a
 * digital copy to a browser on this machine (docs/viewer.md). The page (cli/view/, embedded
 * at build time) is a WebGL2 port of the hybrid bump/relief renderer of seed 000 §5 that
 * `impasto render` runs on the CPU, with the same conventions.
 *
 * The server sends only what it holds in memory: the embedded page, the copy's textures
 * converted once to half floats (pipeline/export/view-pack.h; cached under --cache so the
 * next start skips the conversion) and the copy's copy.json. No request path reaches the
 * file system, so no path can leave the copy. It binds to 127.0.0.1 unless told otherwise.
 * A copy that cannot be read is reported on stderr and the page shows the same message. */
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "commands.h"
#include "exit-codes.h"
#include "copy-load.h"
#include "json-util.h"
#include "log.h"
#include "view-assets.h"
#include "view-pack.h"
#ifdef IMPASTO_HAVE_MHD
#include <microhttpd.h>
#endif

#define VIEW_DEFAULT_PORT 8086

struct view_state {
        const char *copy_dir;
        int cell_px;                  /* > 0: relief boxes classified again at this size */
        struct imp_view_pack pack;    /* empty when the copy could not be read */
        char *copy_json;              /* the copy's copy.json, NULL when unreadable */
        size_t copy_json_size;
        char *error_page;             /* NULL when the copy was read */
        size_t error_page_size;
        char error[1024];
};

static void usage(FILE *f) {
        fprintf(f, "usage: impasto view COPY_DIR [--port N] [--bind ADDR] [--cache DIR | --no-cache] [--cell N]\n"
                   "  serves the copy to a browser at http://ADDR:N/ (default 127.0.0.1:%d; --port 0 picks a free port)\n"
                   "  --cache DIR  where the converted textures are kept (default $XDG_CACHE_HOME/impasto/view)\n"
                   "  --cell N     classify the relief again into boxes of NxN texels (the box-size benchmark)\n",
                   VIEW_DEFAULT_PORT);
}

static void default_cache_dir(char *ret, size_t size) {
        const char *x = getenv("XDG_CACHE_HOME"), *home = getenv("HOME");
        if (x && *x)
                snprintf(ret, size, "%s/impasto/view", x);
        else if (home && *home)
                snprintf(ret, size, "%s/.cache/impasto/view", home);
        else
                ret[0] = 0;
}

/* The textures: from the cache when the copy's files have not changed, else converted
 * (and stored in the cache; a cache that cannot be written costs only a warning). */
static int load_pack(struct view_state *v, const char *cache_dir, struct imp_error *err) {
        char key[32];
        int r = imp_view_pack_key(v->copy_dir, key, sizeof key, err);
        if (r < 0)
                return r;
        if (v->cell_px > 0)
                snprintf(key + strlen(key), sizeof key - strlen(key), "-c%d", v->cell_px);
        if (cache_dir && *cache_dir) {
                struct imp_error cerr = {};
                if (imp_view_pack_cache_load(cache_dir, key, &v->pack, &cerr) >= 0) {
                        log_info("textures from the cache %s/%s.bin", cache_dir, key);
                        return 0;
                }
                if (cerr.msg[0])
                        log_warning("cache: %s (converting again)", cerr.msg);
        }
        struct imp_copy c;
        r = imp_copy_load(v->copy_dir, &c, err);
        if (r >= 0 && v->cell_px > 0)
                r = imp_copy_reclassify(&c, v->cell_px, err);
        if (r >= 0)
                r = imp_view_pack_build(&c, &v->pack, err);
        imp_copy_done(&c);
        if (r < 0)
                return r;
        if (cache_dir && *cache_dir) {
                struct imp_error cerr = {};
                if (imp_view_pack_cache_save(cache_dir, key, &v->pack, &cerr) < 0)
                        log_warning("cache: %s (the copy is served without one)", cerr.msg[0] ? cerr.msg : "not written");
        }
        return 0;
}

static char *read_text(const char *path, size_t *ret_size) {
        FILE *f = fopen(path, "re");
        if (!f)
                return NULL;
        char *buf = NULL;
        size_t cap = 0, n = 0;
        for (;;) {
                if (n + 4096 + 1 > cap) {
                        char *nb = realloc(buf, cap = 2 * cap + 8192);
                        if (!nb) {
                                free(buf);
                                fclose(f);
                                return NULL;
                        }
                        buf = nb;
                }
                size_t k = fread(buf + n, 1, 4096, f);
                n += k;
                if (k < 4096)
                        break;
        }
        fclose(f);
        buf[n] = 0;
        *ret_size = n;
        return buf;
}

static const struct imp_view_asset *asset(const char *path) {
        for (const struct imp_view_asset *a = imp_view_assets; a->path; a++)
                if (!strcmp(a->path, path))
                        return a;
        return NULL;
}

/* error.html with @COPY@ and @MESSAGE@ replaced by the HTML-escaped values. */
static char *error_page(const char *copy_dir, const char *msg, size_t *ret_size) {
        const struct imp_view_asset *a = asset("/error.html");
        if (!a)
                return NULL;
        char *buf = NULL;
        size_t size = 0;
        FILE *f = open_memstream(&buf, &size);
        if (!f)
                return NULL;
        for (const char *p = (const char *) a->data; *p;) {
                const char *val = !strncmp(p, "@COPY@", 6) ? copy_dir : !strncmp(p, "@MESSAGE@", 9) ? msg : NULL;
                if (!val) {
                        fputc(*p++, f);
                        continue;
                }
                p += val == copy_dir ? 6 : 9;
                for (const char *q = val; *q; q++)
                        switch (*q) {
                        case '<': fputs("&lt;", f); break;
                        case '>': fputs("&gt;", f); break;
                        case '&': fputs("&amp;", f); break;
                        case '"': fputs("&quot;", f); break;
                        default: fputc(*q, f);
                        }
        }
        fclose(f);
        *ret_size = size;
        return buf;
}

#ifdef IMPASTO_HAVE_MHD
static enum MHD_Result reply(struct MHD_Connection *conn, unsigned status, const char *mime, const void *data,
                             size_t size) {
        struct MHD_Response *resp =
                MHD_create_response_from_buffer(size, (void *) data, MHD_RESPMEM_PERSISTENT);
        if (!resp)
                return MHD_NO;
        MHD_add_response_header(resp, "Content-Type", mime);
        MHD_add_response_header(resp, "X-Content-Type-Options", "nosniff");
        MHD_add_response_header(resp, "Cache-Control", "no-cache");
        MHD_add_response_header(resp, "Content-Security-Policy",
                                "default-src 'self'; style-src 'self' 'unsafe-inline'; img-src 'self' data:");
        enum MHD_Result r = MHD_queue_response(conn, status, resp);
        MHD_destroy_response(resp);
        return r;
}

static enum MHD_Result reply_text(struct MHD_Connection *conn, unsigned status, const char *text) {
        return reply(conn, status, "text/plain; charset=utf-8", text, strlen(text));
}

/* Routes: the page's files, /copy/meta.json, /copy/textures.bin, /copy/copy.json. */
static enum MHD_Result handle(void *cls, struct MHD_Connection *conn, const char *url, const char *method,
                              const char *version, const char *upload, size_t *upload_size, void **con_cls) {
        const struct view_state *v = cls;
        if (strcmp(method, "GET") && strcmp(method, "HEAD"))
                return reply_text(conn, MHD_HTTP_METHOD_NOT_ALLOWED, "only GET and HEAD\n");
        if (!strcmp(url, "/"))
                url = "/index.html";
        if (!strncmp(url, "/copy/", 6)) {
                if (v->error_page)
                        return reply_text(conn, MHD_HTTP_SERVICE_UNAVAILABLE, v->error);
                if (!strcmp(url, "/copy/meta.json"))
                        return reply(conn, MHD_HTTP_OK, "application/json", v->pack.meta, v->pack.meta_size);
                if (!strcmp(url, "/copy/textures.bin"))
                        return reply(conn, MHD_HTTP_OK, "application/octet-stream", v->pack.data, v->pack.size);
                if (!strcmp(url, "/copy/copy.json") && v->copy_json)
                        return reply(conn, MHD_HTTP_OK, "application/json", v->copy_json, v->copy_json_size);
                return reply_text(conn, MHD_HTTP_NOT_FOUND, "not found\n");
        }
        if (v->error_page && (!strcmp(url, "/index.html") || !strcmp(url, "/bench.html")))
                return reply(conn, MHD_HTTP_INTERNAL_SERVER_ERROR, "text/html; charset=utf-8", v->error_page,
                             v->error_page_size);
        const struct imp_view_asset *a = asset(url);
        if (!a || !strcmp(url, "/error.html"))
                return reply_text(conn, MHD_HTTP_NOT_FOUND, "not found\n");
        return reply(conn, MHD_HTTP_OK, a->mime, a->data, a->size);
}

/* --bind: a numeric IPv4 or IPv6 address. */
static int parse_bind(const char *s, int port, struct sockaddr_storage *ret, bool *ret_v6, bool *ret_loopback) {
        memset(ret, 0, sizeof *ret);
        struct sockaddr_in *a4 = (struct sockaddr_in *) ret;
        struct sockaddr_in6 *a6 = (struct sockaddr_in6 *) ret;
        if (inet_pton(AF_INET, s, &a4->sin_addr) == 1) {
                a4->sin_family = AF_INET;
                a4->sin_port = htons((uint16_t) port);
                *ret_v6 = false;
                *ret_loopback = (ntohl(a4->sin_addr.s_addr) >> 24) == 127;
                return 0;
        }
        if (inet_pton(AF_INET6, s, &a6->sin6_addr) == 1) {
                a6->sin6_family = AF_INET6;
                a6->sin6_port = htons((uint16_t) port);
                *ret_v6 = true;
                *ret_loopback = IN6_IS_ADDR_LOOPBACK(&a6->sin6_addr);
                return 0;
        }
        return -EINVAL;
}

static int serve(struct view_state *v, const char *bind_addr, int port) {
        struct sockaddr_storage sa;
        bool v6, loopback;
        if (parse_bind(bind_addr, port, &sa, &v6, &loopback) < 0) {
                log_error("--bind: expected a numeric IPv4 or IPv6 address, got '%s'", bind_addr);
                return 2;
        }
        if (!loopback)
                log_warning("--bind %s: the copy is served to the network, not only to this machine", bind_addr);
        sigset_t ss;
        sigemptyset(&ss);
        sigaddset(&ss, SIGINT);
        sigaddset(&ss, SIGTERM);
        pthread_sigmask(SIG_BLOCK, &ss, NULL);   /* before MHD's thread starts: it inherits the mask */
        struct MHD_Daemon *d = MHD_start_daemon(
                MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_ERROR_LOG | (v6 ? MHD_USE_IPv6 : 0), (uint16_t) port, NULL,
                NULL, handle, v, MHD_OPTION_SOCK_ADDR, (struct sockaddr *) &sa, MHD_OPTION_CONNECTION_LIMIT, 64,
                MHD_OPTION_CONNECTION_TIMEOUT, 30, MHD_OPTION_END);
        if (!d) {
                log_error("cannot listen on %s port %d: %s", bind_addr, port, strerror(errno ? errno : EADDRINUSE));
                return 1;
        }
        const union MHD_DaemonInfo *info = MHD_get_daemon_info(d, MHD_DAEMON_INFO_BIND_PORT);
        int bound = info ? info->port : port;
        printf("impasto view: %s at http://%s%s%s:%d/ (Ctrl-C to stop)\n", v->error_page ? "an error page" : v->copy_dir,
               v6 ? "[" : "", bind_addr, v6 ? "]" : "", bound);
        fflush(stdout);
        int sig = 0;
        sigwait(&ss, &sig);
        MHD_stop_daemon(d);
        return v->error_page ? 3 : 0;
}
#endif

static int run(int argc, char **argv) {
        int port = VIEW_DEFAULT_PORT;
        const char *bind_addr = "127.0.0.1";
        char cache[PATH_MAX];
        default_cache_dir(cache, sizeof cache);
        static const struct option longopts[] = {
                { "port", required_argument, NULL, 'p' }, { "bind", required_argument, NULL, 'b' },
                { "cache", required_argument, NULL, 'c' }, { "no-cache", no_argument, NULL, 'n' },
                { "cell", required_argument, NULL, 'C' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c, cell = 0;
        while ((c = getopt_long(argc, argv, "p:b:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'p': {
                        char *end;
                        long p = strtol(optarg, &end, 10);
                        if (end == optarg || *end || p < 0 || p > 65535) {
                                log_error("--port: expected 0..65535, got '%s'", optarg);
                                return 2;
                        }
                        port = (int) p;
                        break;
                }
                case 'b': bind_addr = optarg; break;
                case 'c': snprintf(cache, sizeof cache, "%s", optarg); break;
                case 'n': cache[0] = 0; break;
                case 'C': {
                        char *end;
                        long n = strtol(optarg, &end, 10);
                        if (end == optarg || *end || n < 2 || n > 4096) {
                                log_error("--cell: expected 2..4096 texels, got '%s'", optarg);
                                return 2;
                        }
                        cell = (int) n;
                        break;
                }
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return 2;
                }
        if (optind + 1 != argc) {
                log_error("expected one COPY_DIR");
                usage(stderr);
                return 2;
        }
        /* nothing there: bad input at once, like every command (the error page below is for a
         * copy that exists but cannot be read, shown where the operator looks: the browser) */
        struct stat st;
        int sr = stat(argv[optind], &st);
        if (sr < 0 || !S_ISDIR(st.st_mode)) {
                log_error("%s: %s (expected a digital copy directory)", argv[optind],
                          sr < 0 ? strerror(errno) : "not a directory");
                return IMP_EXIT_BAD_INPUT;
        }
        struct view_state v = { .copy_dir = argv[optind], .cell_px = cell };
        struct imp_error err = {};
        int r = load_pack(&v, cache, &err);
        if (r < 0) {
                snprintf(v.error, sizeof v.error, "%s", err.msg[0] ? err.msg : strerror(-r));
                log_error("%s: not a readable digital copy: %s", v.copy_dir, v.error);
                v.error_page = error_page(v.copy_dir, v.error, &v.error_page_size);
                if (!v.error_page)
                        return 3;
        } else {
                char path[PATH_MAX];
                snprintf(path, sizeof path, "%s/copy.json", v.copy_dir);
                v.copy_json = read_text(path, &v.copy_json_size);
        }
#ifdef IMPASTO_HAVE_MHD
        int ret = serve(&v, bind_addr, port);
#else
        log_error("this impasto was built without libmicrohttpd: `impasto view` cannot serve (install libmicrohttpd-dev)");
        int ret = 1;
#endif
        imp_view_pack_done(&v.pack);
        free(v.copy_json);
        free(v.error_page);
        return ret;
}

const struct imp_command imp_cmd_view = {
        .name = "view",
        .summary = "relight and measure a digital copy in the browser (WebGL2)",
        .run = run,
};
