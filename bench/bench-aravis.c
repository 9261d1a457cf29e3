/* Sustained GigE Vision capture through impasto's camera interface (backend "aravis"):
 * open the camera by address, set ROI and pixel format, start, grab for a fixed time, stop.
 * Counts the frames received, the frames lost (gaps in the GVSP block id), incomplete
 * frames (-EIO from grab), the stream's own counters, and the process's CPU time over the
 * grab window (getrusage, all threads: the Aravis receive thread included).
 *
 * The camera runs in another process (arv-fake-gv-camera-0.8 or `impasto sim serve`), so
 * that its CPU is not charged to the client; its frame rate (AcquisitionFrameRate) is not
 * part of impasto's camera interface and is set beforehand (bench/capture-vs-arv.sh does
 * it with arv-tool-0.8). The peer for the same measurement is arv-camera-test-0.8.
 *
 * Usage: bench-aravis [--address A] [--duration-s S] [--width W --height H]
 *                     [--format Mono8|Mono12|Mono16] [--buffers N] [--timeout-ms T]
 * Prints one line of key=value pairs (parsed by bench/capture-vs-arv.sh). Exit 77 when no
 * camera answers at the address (the benchmark is skipped, not passed). */
#include <errno.h>
#include <getopt.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include "camera.h"
#include "exit-codes.h"

#define OPEN_TIMEOUT_MS 3000
#define GV1_BLOCK_ID_MAX 0xffffu        /* GVSP 1.x block ids are 16 bit and skip 0 on wrap */

struct options {
        const char *address;
        double duration_s;
        unsigned width, height;         /* 0: keep the camera's */
        enum imp_pixel_format format;   /* NONE: keep the camera's */
        unsigned n_buffers;             /* 0: the interface's default (4), as the daemon */
        unsigned timeout_ms;
};

struct tally {
        uint64_t frames, bytes;
        uint64_t lost;                  /* block ids skipped between frames received */
        uint64_t incomplete;            /* grab answered -EIO */
        uint64_t timeouts;
        uint64_t first_id, last_id;
        struct imp_frame_meta last;     /* stream counters as of the last good frame */
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + (double) ts.tv_nsec * 1e-9;
}

static double cpu_s(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return (double) ru.ru_utime.tv_sec + (double) ru.ru_utime.tv_usec * 1e-6 +
               (double) ru.ru_stime.tv_sec + (double) ru.ru_stime.tv_usec * 1e-6;
}

static long max_rss_kb(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_maxrss;
}

/* Frames between two received block ids that never arrived. Ids above 16 bit are GVSP 2.x
 * (64-bit, no wrap in practice). */
static uint64_t ids_skipped(uint64_t prev, uint64_t id) {
        if (id > prev)
                return id - prev - 1;
        if (prev <= GV1_BLOCK_ID_MAX)
                return (GV1_BLOCK_ID_MAX - prev) + (id - 1);
        return 0;       /* id went backwards on a 64-bit counter: a restart, not a loss */
}

static void tally_frame(struct tally *t, const struct imp_frame *f) {
        if (t->frames == 0)
                t->first_id = f->meta.frame_id;
        else
                t->lost += ids_skipped(t->last_id, f->meta.frame_id);
        t->last_id = f->meta.frame_id;
        t->frames++;
        t->bytes += f->size;
        t->last = f->meta;
}

static int parse_options(int argc, char **argv, struct options *o) {
        static const struct option longopts[] = {
                { "address", required_argument, NULL, 'a' },
                { "duration-s", required_argument, NULL, 'd' },
                { "width", required_argument, NULL, 'w' },
                { "height", required_argument, NULL, 'h' },
                { "format", required_argument, NULL, 'f' },
                { "buffers", required_argument, NULL, 'b' },
                { "timeout-ms", required_argument, NULL, 't' },
                {}
        };
        *o = (struct options) { .address = "127.0.0.1", .duration_s = 10, .timeout_ms = 2000 };
        int c, r;
        while ((c = getopt_long(argc, argv, "a:d:w:h:f:b:t:", longopts, NULL)) >= 0) {
                switch (c) {
                case 'a': o->address = optarg; break;
                case 'd': o->duration_s = strtod(optarg, NULL); break;
                case 'w': o->width = (unsigned) strtoul(optarg, NULL, 10); break;
                case 'h': o->height = (unsigned) strtoul(optarg, NULL, 10); break;
                case 'b': o->n_buffers = (unsigned) strtoul(optarg, NULL, 10); break;
                case 't': o->timeout_ms = (unsigned) strtoul(optarg, NULL, 10); break;
                case 'f':
                        if ((r = imp_pixel_format_from_string(optarg)) < 0)
                                return r;
                        o->format = (enum imp_pixel_format) r;
                        break;
                default: return -EINVAL;
                }
        }
        if (o->duration_s <= 0 || (o->width == 0) != (o->height == 0))
                return -EINVAL;
        return 0;
}

static int configure(struct imp_camera *cam, const struct options *o) {
        int r;
        if (o->format != IMP_PIXEL_NONE && (r = imp_camera_set_pixel_format(cam, o->format)) < 0) {
                fprintf(stderr, "bench-aravis: pixel format %s: %s (%s)\n",
                        imp_pixel_format_to_string(o->format), strerror(-r), imp_camera_last_error(cam));
                return r;
        }
        if (o->width && (r = imp_camera_set_roi(cam, 0, 0, o->width, o->height)) < 0) {
                fprintf(stderr, "bench-aravis: ROI %ux%u: %s (%s)\n", o->width, o->height,
                        strerror(-r), imp_camera_last_error(cam));
                return r;
        }
        return 0;
}

/* Grabs until duration_s has passed since the first frame; the window starts at the first
 * frame so that connection and stream set-up are not counted. */
static int grab_loop(struct imp_camera *cam, const struct options *o, struct tally *t,
                     double *ret_wall_s, double *ret_cpu_s) {
        double t0 = 0, c0 = 0, t_end = now_s() + o->duration_s + 5;   /* first frame within 5 s */
        for (;;) {
                const struct imp_frame *f;
                int r = imp_camera_grab(cam, o->timeout_ms, &f);
                double now = now_s();
                if (r == 0) {
                        if (t->frames == 0) {
                                t0 = now;
                                c0 = cpu_s();
                                t_end = t0 + o->duration_s;
                        }
                        tally_frame(t, f);
                } else if (r == -EIO)
                        t->incomplete++;
                else if (r == -ETIMEDOUT)
                        t->timeouts++;
                else {
                        fprintf(stderr, "bench-aravis: grab: %s (%s)\n", strerror(-r),
                                imp_camera_last_error(cam));
                        return r;
                }
                if (now >= t_end)
                        break;
        }
        if (t->frames == 0)
                return -ETIMEDOUT;
        *ret_wall_s = now_s() - t0;
        *ret_cpu_s = cpu_s() - c0;
        return 0;
}

static void report(const struct imp_camera_info *info, const struct tally *t, double wall_s,
                   double window_cpu_s) {
        /* The first frame opens the window: the rate counts the intervals after it. */
        double fps = t->frames > 1 ? (double) (t->frames - 1) / wall_s : 0;
        printf("client=impasto width=%u height=%u format=%s frames=%" PRIu64 " wall_s=%.3f fps=%.3f"
               " mib_s=%.3f lost=%" PRIu64 " incomplete=%" PRIu64 " timeouts=%" PRIu64
               " underruns=%" PRIu64 " failures=%" PRIu64 " missing_packets=%" PRIu64
               " resent_packets=%" PRIu64 " first_id=%" PRIu64 " last_id=%" PRIu64
               " window_cpu_s=%.3f cpu_ms_per_frame=%.4f total_cpu_s=%.3f maxrss_kb=%ld\n",
               info->width, info->height, imp_pixel_format_to_string(info->pixel_format),
               t->frames, wall_s, fps, (double) t->bytes / wall_s / (1024.0 * 1024.0), t->lost,
               t->incomplete, t->timeouts, t->last.n_underruns, t->last.n_failures,
               t->last.n_missing_packets, t->last.n_resent_packets, t->first_id, t->last_id,
               window_cpu_s, t->frames ? 1000.0 * window_cpu_s / (double) t->frames : 0,
               cpu_s(), max_rss_kb());
}

int main(int argc, char **argv) {
        struct options o;
        int r = parse_options(argc, argv, &o);
        if (r < 0) {
                fprintf(stderr, "usage: bench-aravis [--address A] [--duration-s S] [--width W --height H]"
                                " [--format Mono8|Mono12|Mono16] [--buffers N] [--timeout-ms T]\n");
                return 2;
        }
        _cleanup_(imp_camera_closep) struct imp_camera *cam = NULL;
        r = imp_camera_open("aravis", o.address, OPEN_TIMEOUT_MS, &cam);
        if (r < 0) {
                fprintf(stderr, "bench-aravis: camera %s: %s, skipping\n", o.address, strerror(-r));
                return r == -ENOENT ? 1 : IMP_EXIT_SKIP;    /* -ENOENT: built without Aravis */
        }
        if (configure(cam, &o) < 0)
                return 1;
        struct imp_camera_info info;
        if ((r = imp_camera_get_info(cam, &info)) < 0) {
                fprintf(stderr, "bench-aravis: camera info: %s\n", strerror(-r));
                return 1;
        }
        if ((r = imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = o.n_buffers })) < 0) {
                fprintf(stderr, "bench-aravis: start: %s (%s)\n", strerror(-r), imp_camera_last_error(cam));
                return 1;
        }
        struct tally t = {};
        double wall_s = 0, window_cpu_s = 0;
        r = grab_loop(cam, &o, &t, &wall_s, &window_cpu_s);
        (void) imp_camera_stop(cam);
        if (r < 0) {
                fprintf(stderr, "bench-aravis: no frame: %s\n", strerror(-r));
                return 1;
        }
        report(&info, &t, wall_s, window_cpu_s);
        return 0;
}
