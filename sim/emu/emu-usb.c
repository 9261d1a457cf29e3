/* USB DLP projector emulator: a umockdev testbed USB device (sysfs attributes, the binary
 * "descriptors" file, /dev/bus/usb/BBB/DDD) whose usbdevfs ioctls are answered here, the
 * URBs libusb submits included, speaking the command set of docs/projector-usb.md.
 *
 * URBs: libusb submits asynchronous URBs (USBDEVFS_SUBMITURB) and reaps them with
 * USBDEVFS_REAPURBNDELAY when poll() says the fd is writable. umockdev's fd is always
 * writable, so libusb polls in a loop; an URB with nothing to answer yet stays "in flight"
 * here and REAPURBNDELAY answers EAGAIN. The submitted URB is kept as the resolved
 * UMockdevIoctlData (its buffer resolved as a child); at reap time the local copy is
 * updated and linked into the REAP argument with umockdev_ioctl_data_set_ptr(), so
 * umockdev writes the URB, its buffer and the pointer back to the caller (the pattern of
 * libusb's own tests/umockdev.c). */
#include <linux/usbdevice_fs.h>
#include <sys/ioctl.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <umockdev.h>
#include "emu.h"

#define FRAME_MAX 512
#define HDR_LEN 8
#define CRC_LEN 2
#define MAGIC 0x4A50u                   /* "PJ" little-endian */
#define EP_OUT 0x01
#define EP_IN 0x81
#define MAX_PATTERNS 256

enum { OP_GET_INFO = 0x01, OP_UPLOAD_BEGIN = 0x10, OP_UPLOAD_PATTERN = 0x11, OP_UPLOAD_END = 0x12,
       OP_SHOW = 0x20, OP_DARK = 0x21, OP_TRIGGER = 0x22, OP_GET_STATUS = 0x30, OP_REPLY = 0x80 };
enum { ST_OK = 0, ST_BAD_FRAME = 1, ST_BAD_OPCODE = 2, ST_BAD_LENGTH = 3, ST_BAD_ARG = 4,
       ST_BAD_STATE = 5, ST_BUSY = 6, ST_FAULT = 7 };

struct imp_emu_usb {
        struct imp_emu_usb_config cfg;
        char devnode[64];
        char syspath[160];
        struct imp_emu_rig *rig;
        UMockdevTestbed *tb;
        UMockdevIoctlBase *handler;
        pthread_mutex_t lock;
        GQueue done;                    /* completed URBs (UMockdevIoctlData *) to reap */
        GQueue waiting_in;              /* bulk IN URBs without a reply yet */
        uint8_t reply[FRAME_MAX];       /* reply to the last command, not yet read */
        size_t reply_len;
        uint8_t cached[FRAME_MAX];      /* reply to the last executed sequence number */
        size_t cached_len;
        uint16_t cached_seq;
        uint8_t cached_op;
        bool have_cached;
        bool halted_out, halted_in, gone;
        unsigned stall_countdown, stall_times;
        unsigned drop_countdown, drop_times;
        /* device state */
        struct imp_pattern patterns[MAX_PATTERNS];
        unsigned n_uploaded, upload_n, upload_next;
        bool uploading;
        int shown;
        uint64_t shown_at_ns;
        uint32_t show_count;
        unsigned n_commands, n_clear_halts, n_triggers;
};

bool imp_emu_usb_available(void) {
        return imp_emu_gpio_available();
}

static uint16_t crc16(const uint8_t *p, size_t n) {   /* CRC-16/CCITT-FALSE */
        uint16_t crc = 0xFFFF;
        for (size_t i = 0; i < n; i++) {
                crc ^= (uint16_t) (p[i] << 8);
                for (int b = 0; b < 8; b++)
                        crc = (uint16_t) (crc & 0x8000 ? (crc << 1) ^ 0x1021 : crc << 1);
        }
        return crc;
}

static uint16_t get16(const uint8_t *p) { return (uint16_t) (p[0] | p[1] << 8); }
static uint32_t get32(const uint8_t *p) { return (uint32_t) get16(p) | (uint32_t) get16(p + 2) << 16; }
static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t) v; p[1] = (uint8_t) (v >> 8); }
static void put32(uint8_t *p, uint32_t v) { put16(p, (uint16_t) v); put16(p + 2, (uint16_t) (v >> 16)); }
static void put64(uint8_t *p, uint64_t v) { put32(p, (uint32_t) v); put32(p + 4, (uint32_t) (v >> 32)); }

static uint64_t now_ns(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

/* Builds the reply frame for the command in e->reply. */
static void build_reply(struct imp_emu_usb *e, uint8_t opcode, uint8_t status, uint16_t seq,
                        const uint8_t *payload, uint16_t len) {
        uint8_t *f = e->reply;
        put16(f, MAGIC);
        f[2] = (uint8_t) (opcode | OP_REPLY);
        f[3] = status;
        put16(f + 4, len);
        put16(f + 6, seq);
        if (len)
                memcpy(f + HDR_LEN, payload, len);
        put16(f + HDR_LEN + len, crc16(f, HDR_LEN + len));
        e->reply_len = HDR_LEN + len + CRC_LEN;
}

static uint8_t decode_pattern(const uint8_t *p, struct imp_pattern *ret) {
        static const enum imp_pattern_kind kinds[] = { IMP_PAT_NONE, IMP_PAT_WHITE, IMP_PAT_BLACK,
                                                       IMP_PAT_GRAY, IMP_PAT_PHASE };
        if (p[0] >= sizeof kinds / sizeof kinds[0] || p[0] == 0 || p[1] > 1 || (p[4] & ~1u))
                return ST_BAD_ARG;
        *ret = (struct imp_pattern) {
                .kind = kinds[p[0]], .axis = p[1], .bit = p[2], .nbits = p[3], .inverse = p[4] & 1,
                .step = get16(p + 6), .steps = get16(p + 8), .period_px = get32(p + 10) / 100.0,
        };
        return ST_OK;
}

/* Executes one well-formed command; returns the reply status, fills out/out_len. */
static uint8_t execute(struct imp_emu_usb *e, uint8_t op, const uint8_t *in, uint16_t len,
                       uint8_t *out, uint16_t *out_len) {
        *out_len = 0;
        switch (op) {
        case OP_GET_INFO:
                if (len != 0)
                        return ST_BAD_LENGTH;
                memset(out, 0, 72);
                snprintf((char *) out, 32, "%s", e->cfg.model);
                snprintf((char *) out + 32, 32, "%s", e->cfg.serial);
                put16(out + 64, (uint16_t) e->cfg.width);
                put16(out + 66, (uint16_t) e->cfg.height);
                put16(out + 68, (uint16_t) e->cfg.max_patterns);
                put16(out + 70, 0x0100);         /* firmware 1.0 */
                *out_len = 72;
                return ST_OK;
        case OP_UPLOAD_BEGIN: {
                if (len != 2)
                        return ST_BAD_LENGTH;
                unsigned n = get16(in);
                if (n == 0 || n > e->cfg.max_patterns)
                        return ST_BAD_ARG;
                e->uploading = true;
                e->upload_n = n;
                e->upload_next = 0;
                e->n_uploaded = 0;
                e->shown = -1;
                imp_emu_rig_set_pattern_desc(e->rig, -1, NULL);
                return ST_OK;
        }
        case OP_UPLOAD_PATTERN: {
                if (len != 16)
                        return ST_BAD_LENGTH;
                if (!e->uploading)
                        return ST_BAD_STATE;
                if (get16(in) != e->upload_next)
                        return ST_BAD_ARG;
                uint8_t st = decode_pattern(in + 2, &e->patterns[e->upload_next]);
                if (st == ST_OK)
                        e->upload_next++;
                return st;
        }
        case OP_UPLOAD_END:
                if (len != 2)
                        return ST_BAD_LENGTH;
                if (!e->uploading)
                        return ST_BAD_STATE;
                if (get16(in) != e->upload_n || e->upload_next != e->upload_n)
                        return ST_BAD_ARG;
                e->uploading = false;
                e->n_uploaded = e->upload_n;
                return ST_OK;
        case OP_SHOW: {
                if (len != 2)
                        return ST_BAD_LENGTH;
                if (e->uploading || e->n_uploaded == 0)
                        return ST_BAD_STATE;
                unsigned i = get16(in);
                if (i >= e->n_uploaded)
                        return ST_BAD_ARG;
                e->shown = (int) i;
                e->shown_at_ns = now_ns();
                e->show_count++;
                imp_emu_rig_set_pattern_desc(e->rig, (int) i, &e->patterns[i]);
                return ST_OK;
        }
        case OP_DARK:
                if (len != 0)
                        return ST_BAD_LENGTH;
                e->shown = -1;
                imp_emu_rig_set_pattern_desc(e->rig, -1, NULL);
                return ST_OK;
        case OP_TRIGGER:
                if (len != 0)
                        return ST_BAD_LENGTH;
                e->n_triggers++;
                return ST_OK;
        case OP_GET_STATUS:
                if (len != 0)
                        return ST_BAD_LENGTH;
                put16(out, (uint16_t) (int16_t) e->shown);
                put16(out + 2, (uint16_t) e->n_uploaded);
                out[4] = 0;                      /* fault latched */
                out[5] = 0;
                put16(out + 6, 0);               /* fault code */
                put64(out + 8, e->shown_at_ns);
                put32(out + 16, e->show_count);
                *out_len = 20;
                return ST_OK;
        default:
                return ST_BAD_OPCODE;
        }
}

/* A command frame arrived on the bulk OUT endpoint: answer it into e->reply. */
static void on_command(struct imp_emu_usb *e, const uint8_t *f, size_t n) {
        uint8_t out[FRAME_MAX];
        uint16_t out_len = 0;
        if (n < HDR_LEN + CRC_LEN || get16(f) != MAGIC) {
                build_reply(e, 0, ST_BAD_FRAME, n >= HDR_LEN ? get16(f + 6) : 0, NULL, 0);
                return;
        }
        uint8_t op = f[2];
        uint16_t len = get16(f + 4), seq = get16(f + 6);
        if (HDR_LEN + (size_t) len + CRC_LEN != n || crc16(f, HDR_LEN + len) != get16(f + HDR_LEN + len)) {
                build_reply(e, op, ST_BAD_FRAME, seq, NULL, 0);
                return;
        }
        /* A retry of the last executed command (same sequence number and opcode) gets the
         * same answer without running it again. */
        if (e->have_cached && seq == e->cached_seq && op == e->cached_op && op != OP_GET_STATUS) {
                memcpy(e->reply, e->cached, e->cached_len);
                e->reply_len = e->cached_len;
                return;
        }
        uint8_t st = execute(e, op, f + HDR_LEN, len, out, &out_len);
        build_reply(e, op, st, seq, out, out_len);
        memcpy(e->cached, e->reply, e->reply_len);
        e->cached_len = e->reply_len;
        e->cached_seq = seq;
        e->cached_op = op;
        e->have_cached = true;
}

static struct usbdevfs_urb *urb_of(UMockdevIoctlData *d) {
        return (struct usbdevfs_urb *) d->data;
}

static void complete_urb_locked(struct imp_emu_usb *e, UMockdevIoctlData *urb_data, int status,
                                int actual_length) {
        struct usbdevfs_urb *urb = urb_of(urb_data);
        urb->status = status;
        urb->actual_length = actual_length;
        g_queue_push_tail(&e->done, urb_data);
}

/* Hands the pending reply to the oldest waiting IN URB. */
static void deliver_locked(struct imp_emu_usb *e) {
        if (!e->reply_len || g_queue_is_empty(&e->waiting_in))
                return;
        UMockdevIoctlData *d = g_queue_pop_head(&e->waiting_in);
        struct usbdevfs_urb *urb = urb_of(d);
        size_t n = IMP_MIN((size_t) urb->buffer_length, e->reply_len);
        memcpy(urb->buffer, e->reply, n);
        e->reply_len = 0;
        complete_urb_locked(e, d, 0, (int) n);
}

static const uint8_t *string_descriptor(struct imp_emu_usb *e, unsigned index, uint8_t *buf, size_t *ret_len) {
        const char *s = index == 1 ? "impasto" : index == 2 ? e->cfg.model : index == 3 ? e->cfg.serial : NULL;
        if (index == 0) {
                static const uint8_t langids[] = { 4, 3, 0x09, 0x04 };
                *ret_len = sizeof langids;
                return langids;
        }
        if (!s)
                return NULL;
        size_t n = IMP_MIN(strlen(s), (size_t) 126);
        buf[0] = (uint8_t) (2 + 2 * n);
        buf[1] = 3;
        for (size_t i = 0; i < n; i++) {
                buf[2 + 2 * i] = (uint8_t) s[i];
                buf[3 + 2 * i] = 0;
        }
        *ret_len = 2 + 2 * n;
        return buf;
}

static const uint8_t config_descriptor[] = {
        0x09, 0x02, 0x20, 0x00, 0x01, 0x01, 0x00, 0x80, 0x32,  /* config 1, 1 interface, 100 mA */
        0x09, 0x04, 0x00, 0x00, 0x02, 0xFF, 0x00, 0x00, 0x00,  /* interface 0: vendor class, 2 EPs */
        0x07, 0x05, EP_OUT, 0x02, 0x00, 0x02, 0x00,            /* bulk OUT, 512 bytes */
        0x07, 0x05, EP_IN, 0x02, 0x00, 0x02, 0x00,             /* bulk IN, 512 bytes */
};

static void device_descriptor(const struct imp_emu_usb *e, uint8_t d[18]) {
        const uint8_t v[18] = { 0x12, 0x01, 0x00, 0x02, 0x00, 0x00, 0x00, 0x40,
                                (uint8_t) e->cfg.vid, (uint8_t) (e->cfg.vid >> 8),
                                (uint8_t) e->cfg.pid, (uint8_t) (e->cfg.pid >> 8),
                                0x00, 0x01, 0x01, 0x02, 0x03, 0x01 };
        memcpy(d, v, sizeof v);
}

/* Control transfers on endpoint 0: the standard GET_DESCRIPTOR only; anything else stalls. */
static void control_locked(struct imp_emu_usb *e, UMockdevIoctlData *d) {
        struct usbdevfs_urb *urb = urb_of(d);
        uint8_t *b = urb->buffer;
        if (urb->buffer_length < 8) {
                complete_urb_locked(e, d, -EINVAL, 0);
                return;
        }
        unsigned type = b[0], req = b[1], value = get16(b + 2), wlen = get16(b + 6);
        uint8_t tmp[256];
        const uint8_t *src = NULL;
        size_t n = 0;
        if (type == 0x80 && req == 6) {
                switch (value >> 8) {
                case 1: device_descriptor(e, tmp); src = tmp; n = 18; break;
                case 2: src = config_descriptor; n = sizeof config_descriptor; break;
                case 3: src = string_descriptor(e, value & 0xFF, tmp, &n); break;
                }
        }
        if (!src) {
                complete_urb_locked(e, d, -EPIPE, 0);
                return;
        }
        n = IMP_MIN(n, IMP_MIN((size_t) wlen, (size_t) urb->buffer_length - 8));
        memcpy(b + 8, src, n);
        complete_urb_locked(e, d, 0, (int) n);
}

/* Returns the errno for the SUBMITURB ioctl itself; the URB completes through `done`. */
static int submit_locked(struct imp_emu_usb *e, UMockdevIoctlData *arg) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct usbdevfs_urb), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        struct usbdevfs_urb *urb = urb_of(d);
        if (urb->buffer_length > 0) {
                UMockdevIoctlData *buf = umockdev_ioctl_data_resolve(d, offsetof(struct usbdevfs_urb, buffer),
                                                                     (gsize) urb->buffer_length, &err);
                if (!buf) {
                        g_clear_error(&err);
                        umockdev_ioctl_data_unref(d);
                        return EFAULT;
                }
                umockdev_ioctl_data_unref(buf);  /* the parent holds it */
        }
        if (urb->type == USBDEVFS_URB_TYPE_CONTROL && (urb->endpoint & 0x7F) == 0) {
                control_locked(e, d);
                return 0;
        }
        if (urb->type != USBDEVFS_URB_TYPE_BULK || (urb->endpoint != EP_OUT && urb->endpoint != EP_IN)) {
                umockdev_ioctl_data_unref(d);
                return EINVAL;
        }
        if (urb->endpoint == EP_IN) {
                if (e->halted_in)
                        complete_urb_locked(e, d, -EPIPE, 0);
                else {
                        g_queue_push_tail(&e->waiting_in, d);
                        deliver_locked(e);
                }
                return 0;
        }
        if (e->halted_out) {
                complete_urb_locked(e, d, -EPIPE, 0);
                return 0;
        }
        e->n_commands++;
        if (e->stall_countdown && --e->stall_countdown == 0) {
                if (--e->stall_times > 0)
                        e->stall_countdown = 1;
                e->halted_out = true;
                complete_urb_locked(e, d, -EPIPE, 0);
                return 0;
        }
        on_command(e, urb->buffer, (size_t) urb->buffer_length);
        if (e->drop_countdown && --e->drop_countdown == 0) {
                if (--e->drop_times > 0)
                        e->drop_countdown = 1;
                e->reply_len = 0;
        }
        complete_urb_locked(e, d, 0, urb->buffer_length);
        deliver_locked(e);
        return 0;
}

static int reap_locked(struct imp_emu_usb *e, UMockdevIoctlData *arg) {
        if (g_queue_is_empty(&e->done))
                return e->gone ? ENODEV : EAGAIN;
        GError *err = NULL;
        UMockdevIoctlData *ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(void *), &err);
        if (!ptr) {
                g_clear_error(&err);
                return EFAULT;
        }
        UMockdevIoctlData *d = g_queue_pop_head(&e->done);
        umockdev_ioctl_data_set_ptr(ptr, 0, d);
        umockdev_ioctl_data_unref(d);
        umockdev_ioctl_data_unref(ptr);
        return 0;
}

static int discard_locked(struct imp_emu_usb *e, UMockdevIoctlData *arg) {
        gulong addr = (gulong) *(void **) arg->data;
        for (GList *l = e->waiting_in.head; l; l = l->next) {
                UMockdevIoctlData *d = l->data;
                if (d->client_addr != addr)
                        continue;
                g_queue_delete_link(&e->waiting_in, l);
                complete_urb_locked(e, d, -ENOENT, 0);
                return 0;
        }
        return EINVAL;
}

static int uint_arg(UMockdevIoctlData *arg, unsigned *ret) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(unsigned), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        *ret = *(unsigned *) d->data;
        umockdev_ioctl_data_unref(d);
        return 0;
}

static gboolean on_ioctl(UMockdevIoctlBase *handler, UMockdevIoctlClient *client, gpointer data) {
        struct imp_emu_usb *e = data;
        (void) handler;
        gulong request = umockdev_ioctl_client_get_request(client);
        UMockdevIoctlData *arg = umockdev_ioctl_client_get_arg(client);
        int err = 0;
        unsigned v = 0;
        pthread_mutex_lock(&e->lock);
        if (e->gone && request != USBDEVFS_REAPURBNDELAY && request != USBDEVFS_REAPURB)
                err = ENODEV;
        else
                switch (request) {
                case USBDEVFS_GET_CAPABILITIES: {
                        GError *gerr = NULL;
                        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(uint32_t), &gerr);
                        if (!d) {
                                g_clear_error(&gerr);
                                err = EFAULT;
                                break;
                        }
                        *(uint32_t *) d->data = USBDEVFS_CAP_BULK_CONTINUATION | USBDEVFS_CAP_NO_PACKET_SIZE_LIM |
                                                USBDEVFS_CAP_REAP_AFTER_DISCONNECT | USBDEVFS_CAP_ZERO_PACKET;
                        umockdev_ioctl_data_unref(d);
                        break;
                }
                case USBDEVFS_CLAIMINTERFACE:
                case USBDEVFS_RELEASEINTERFACE:
                        err = uint_arg(arg, &v);
                        if (!err && v != 0)
                                err = ENOENT;
                        break;
                case USBDEVFS_CLEAR_HALT:
                        err = uint_arg(arg, &v);
                        if (err)
                                break;
                        e->n_clear_halts++;
                        if (v == EP_OUT)
                                e->halted_out = false;
                        else if (v == EP_IN)
                                e->halted_in = false;
                        else
                                err = ENOENT;
                        break;
                case USBDEVFS_RESET:
                case USBDEVFS_RESETEP:
                case USBDEVFS_SETINTERFACE:
                case USBDEVFS_SETCONFIGURATION:
                        break;
                case USBDEVFS_GETDRIVER:
                        err = ENODATA;           /* no kernel driver bound */
                        break;
                case USBDEVFS_SUBMITURB: err = submit_locked(e, arg); break;
                case USBDEVFS_REAPURB:
                case USBDEVFS_REAPURBNDELAY: err = reap_locked(e, arg); break;
                case USBDEVFS_DISCARDURB: err = discard_locked(e, arg); break;
                default: err = ENOTTY; break;
                }
        pthread_mutex_unlock(&e->lock);
        umockdev_ioctl_client_complete(client, err ? -1 : 0, err);
        return TRUE;
}

static char *hex(const uint8_t *p, size_t n, char *out) {
        for (size_t i = 0; i < n; i++)
                sprintf(out + 2 * i, "%02x", p[i]);
        out[2 * n] = 0;
        return out;
}

int imp_emu_usb_new(const struct imp_emu_usb_config *cfg, struct imp_emu_rig *rig,
                    struct imp_emu_usb **ret_emu) {
        if (!cfg || !ret_emu)
                return -EINVAL;
        if (!imp_emu_usb_available())
                return -ENOTSUP;
        struct imp_emu_usb *e = calloc(1, sizeof *e);
        if (!e)
                return -ENOMEM;
        e->cfg = *cfg;
        if (!e->cfg.vid && !e->cfg.pid) {
                e->cfg.vid = 0x1d50;
                e->cfg.pid = 0x6020;
        }
        if (!e->cfg.serial)
                e->cfg.serial = "EMU0001";
        if (!e->cfg.model)
                e->cfg.model = "impasto DLP emulator";
        if (!e->cfg.busnum)
                e->cfg.busnum = 1;
        if (!e->cfg.devnum)
                e->cfg.devnum = 5;
        if (!e->cfg.width)
                e->cfg.width = 1280;
        if (!e->cfg.height)
                e->cfg.height = 800;
        if (!e->cfg.max_patterns)
                e->cfg.max_patterns = MAX_PATTERNS;
        e->rig = rig;
        e->shown = -1;
        pthread_mutex_init(&e->lock, NULL);
        g_queue_init(&e->done);
        g_queue_init(&e->waiting_in);
        int r = -EINVAL;
        if (e->cfg.busnum > 255 || e->cfg.devnum > 127 || e->cfg.max_patterns > MAX_PATTERNS ||
            strlen(e->cfg.serial) > 31 || strlen(e->cfg.model) > 31)
                goto fail;
        snprintf(e->devnode, sizeof e->devnode, "/dev/bus/usb/%03u/%03u", e->cfg.busnum, e->cfg.devnum);
        snprintf(e->syspath, sizeof e->syspath, "/sys/devices/pci0000:00/0000:00:14.0/usb%u/%u-1",
                 e->cfg.busnum, e->cfg.busnum);

        uint8_t desc[18 + sizeof config_descriptor];
        device_descriptor(e, desc);
        memcpy(desc + 18, config_descriptor, sizeof config_descriptor);
        char hexbuf[2 * sizeof desc + 1];
        char record[2048];
        /* Attributes end in an escaped newline as in real sysfs; "descriptors" is binary
         * (H:, hex). The ioctl handler is attached before the node exists so that a client
         * woken by the "add" event can already talk to it. */
        snprintf(record, sizeof record,
                 "P: %s\nN: bus/usb/%03u/%03u\nE: SUBSYSTEM=usb\nE: DEVTYPE=usb_device\nE: DRIVER=usb\n"
                 "E: BUSNUM=%03u\nE: DEVNUM=%03u\nE: DEVNAME=%s\nE: PRODUCT=%x/%x/100\n"
                 "A: idVendor=%04x\\n\nA: idProduct=%04x\\n\nA: serial=%s\\n\nA: product=%s\\n\n"
                 "A: manufacturer=impasto\\n\nA: busnum=%u\\n\nA: devnum=%u\\n\nA: speed=480\\n\n"
                 "A: bConfigurationValue=1\\n\nA: bNumConfigurations=1\\n\nA: bNumInterfaces= 1\\n\n"
                 "A: dev=189:%u\\n\nH: descriptors=%s\n",
                 e->syspath + strlen("/sys"), e->cfg.busnum, e->cfg.devnum, e->cfg.busnum, e->cfg.devnum,
                 e->devnode, e->cfg.vid, e->cfg.pid, e->cfg.vid, e->cfg.pid, e->cfg.serial, e->cfg.model,
                 e->cfg.busnum, e->cfg.devnum, (e->cfg.busnum - 1) * 128 + e->cfg.devnum - 1,
                 hex(desc, sizeof desc, hexbuf));
        e->tb = umockdev_testbed_new();
        e->handler = umockdev_ioctl_base_new();
        g_signal_connect(e->handler, "handle-ioctl", G_CALLBACK(on_ioctl), e);
        GError *err = NULL;
        r = -EIO;
        if (!umockdev_testbed_attach_ioctl(e->tb, e->devnode, e->handler, &err) ||
            !umockdev_testbed_add_from_string(e->tb, record, &err)) {
                g_clear_error(&err);
                goto fail;
        }
        *ret_emu = e;
        return 0;
fail:
        imp_emu_usb_free(e);
        return r;
}

static void unref_queue(GQueue *q) {
        UMockdevIoctlData *d;
        while ((d = g_queue_pop_head(q)))
                umockdev_ioctl_data_unref(d);
}

void imp_emu_usb_free(struct imp_emu_usb *e) {
        if (!e)
                return;
        if (e->tb && e->handler)
                umockdev_testbed_detach_ioctl(e->tb, e->devnode, NULL);
        unref_queue(&e->done);
        unref_queue(&e->waiting_in);
        g_clear_object(&e->handler);
        g_clear_object(&e->tb);
        pthread_mutex_destroy(&e->lock);
        free(e);
}

void imp_emu_usb_stall_nth(struct imp_emu_usb *e, unsigned nth, unsigned times) {
        pthread_mutex_lock(&e->lock);
        e->stall_countdown = nth;
        e->stall_times = times ? times : 1;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_usb_drop_reply_nth(struct imp_emu_usb *e, unsigned nth, unsigned times) {
        pthread_mutex_lock(&e->lock);
        e->drop_countdown = nth;
        e->drop_times = times ? times : 1;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_usb_disconnect(struct imp_emu_usb *e) {
        pthread_mutex_lock(&e->lock);
        bool was_gone = e->gone;
        e->gone = true;
        UMockdevIoctlData *d;
        while ((d = g_queue_pop_head(&e->waiting_in)))
                complete_urb_locked(e, d, -ESHUTDOWN, 0);
        pthread_mutex_unlock(&e->lock);
        if (!was_gone)
                umockdev_testbed_remove_device(e->tb, e->syspath);
}

int imp_emu_usb_shown(struct imp_emu_usb *e) {
        pthread_mutex_lock(&e->lock);
        int s = e->shown;
        pthread_mutex_unlock(&e->lock);
        return s;
}

int imp_emu_usb_pattern(struct imp_emu_usb *e, unsigned i, struct imp_pattern *ret) {
        pthread_mutex_lock(&e->lock);
        int r = i < e->n_uploaded ? 0 : -ENOENT;
        if (r == 0)
                *ret = e->patterns[i];
        pthread_mutex_unlock(&e->lock);
        return r;
}

#define COUNTER(name)                                           \
        unsigned imp_emu_usb_##name(struct imp_emu_usb *e) {    \
                pthread_mutex_lock(&e->lock);                   \
                unsigned v = e->name;                           \
                pthread_mutex_unlock(&e->lock);                 \
                return v;                                       \
        }
COUNTER(n_commands)
COUNTER(n_clear_halts)
COUNTER(n_triggers)
