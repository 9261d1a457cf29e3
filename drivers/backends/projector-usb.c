/* Projector backend "usb-dlp": a DLP controller on USB through libusb 1.0, speaking the
 * framed command set of docs/projector-usb.md over one bulk OUT and one bulk IN endpoint of
 * a vendor-specific interface. A stalled endpoint is cleared (libusb_clear_halt) and the
 * same frame re-sent with the same sequence number, at most `retries` times; the device
 * answers a repeated sequence number from its reply cache, so a retry never runs a command
 * twice. A vanished device is -ENODEV from then on. */
#include <inttypes.h>
#include <libusb.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "address.h"
#include "projector.h"

#define USB_DLP_FRAME_MAX 512           /* one high-speed bulk packet */
#define USB_DLP_HDR_LEN 8               /* magic u16, opcode u8, status u8, length u16, seq u16 */
#define USB_DLP_CRC_LEN 2               /* CRC-16/CCITT-FALSE over header + payload */
#define USB_DLP_PAYLOAD_MAX (USB_DLP_FRAME_MAX - USB_DLP_HDR_LEN - USB_DLP_CRC_LEN)
#define USB_DLP_MAGIC 0x4A50u
#define USB_DLP_REPLY 0x80              /* opcode bit set in replies */
#define USB_DLP_PATTERN_DESC_LEN 14
#define USB_DLP_DEFAULT_TIMEOUT_MS 1000
#define USB_DLP_DEFAULT_RETRIES 2       /* re-sends after the first attempt */
#define USB_DLP_STALE_READS 4           /* replies with an old sequence number skipped per command */

enum usb_dlp_opcode {
        OP_GET_INFO = 0x01,
        OP_UPLOAD_BEGIN = 0x10,
        OP_UPLOAD_PATTERN = 0x11,
        OP_UPLOAD_END = 0x12,
        OP_SHOW = 0x20,
        OP_DARK = 0x21,
        OP_TRIGGER = 0x22,
        OP_GET_STATUS = 0x30,
};

enum usb_dlp_status {
        ST_OK = 0, ST_BAD_FRAME = 1, ST_BAD_OPCODE = 2, ST_BAD_LENGTH = 3, ST_BAD_ARG = 4,
        ST_BAD_STATE = 5, ST_BUSY = 6, ST_FAULT = 7,
};

struct usb_dlp {
        libusb_context *ctx;
        libusb_device_handle *h;
        int iface;
        uint8_t ep_out, ep_in;
        unsigned timeout_ms, retries;
        uint16_t seq;
        bool claimed, gone;
        unsigned n_stalls;              /* halts cleared over the handle's life */
        struct imp_projector_info info;
        char error[224];
};

static const char *op_name(uint8_t op) {
        switch (op) {
        case OP_GET_INFO: return "GET_INFO";
        case OP_UPLOAD_BEGIN: return "UPLOAD_BEGIN";
        case OP_UPLOAD_PATTERN: return "UPLOAD_PATTERN";
        case OP_UPLOAD_END: return "UPLOAD_END";
        case OP_SHOW: return "SHOW";
        case OP_DARK: return "DARK";
        case OP_TRIGGER: return "TRIGGER";
        case OP_GET_STATUS: return "GET_STATUS";
        default: return "?";
        }
}

static int fail(struct usb_dlp *u, int r, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
static int fail(struct usb_dlp *u, int r, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(u->error, sizeof u->error, fmt, ap);
        va_end(ap);
        return r;
}

/* libusb's codes mapped once. */
static int errno_of(int lr) {
        switch (lr) {
        case LIBUSB_ERROR_IO: return -EIO;
        case LIBUSB_ERROR_INVALID_PARAM: return -EINVAL;
        case LIBUSB_ERROR_ACCESS: return -EACCES;
        case LIBUSB_ERROR_NO_DEVICE: return -ENODEV;
        case LIBUSB_ERROR_NOT_FOUND: return -ENOENT;
        case LIBUSB_ERROR_BUSY: return -EBUSY;
        case LIBUSB_ERROR_TIMEOUT: return -ETIMEDOUT;
        case LIBUSB_ERROR_OVERFLOW: return -EOVERFLOW;
        case LIBUSB_ERROR_PIPE: return -EPIPE;
        case LIBUSB_ERROR_INTERRUPTED: return -EINTR;
        case LIBUSB_ERROR_NO_MEM: return -ENOMEM;
        case LIBUSB_ERROR_NOT_SUPPORTED: return -EOPNOTSUPP;
        default: return -EIO;
        }
}

static int status_errno(uint8_t st) {
        switch (st) {
        case ST_OK: return 0;
        case ST_BAD_FRAME: return -EBADMSG;
        case ST_BAD_OPCODE: return -EOPNOTSUPP;
        case ST_BAD_LENGTH: return -EPROTO;
        case ST_BAD_ARG: return -EINVAL;
        case ST_BAD_STATE: return -EBADFD;
        case ST_BUSY: return -EBUSY;
        case ST_FAULT: return -EIO;
        default: return -EPROTO;
        }
}

static const char *status_name(uint8_t st) {
        static const char *const names[] = { "OK", "BAD_FRAME", "BAD_OPCODE", "BAD_LENGTH",
                                             "BAD_ARG", "BAD_STATE", "BUSY", "FAULT" };
        return st < sizeof names / sizeof names[0] ? names[st] : "unknown status";
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
static uint64_t get64(const uint8_t *p) { return (uint64_t) get32(p) | (uint64_t) get32(p + 4) << 32; }
static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t) v; p[1] = (uint8_t) (v >> 8); }
static void put32(uint8_t *p, uint32_t v) { put16(p, (uint16_t) v); put16(p + 2, (uint16_t) (v >> 16)); }

static int gone(struct usb_dlp *u, const char *what) {
        u->gone = true;
        return fail(u, -ENODEV, "%s: device disconnected (LIBUSB_ERROR_NO_DEVICE)", what);
}

/* Clears a halted endpoint; 0, or -ENODEV / the clear's own failure. */
static int clear_halt(struct usb_dlp *u, uint8_t ep, const char *what) {
        u->n_stalls++;
        int lr = libusb_clear_halt(u->h, ep);
        if (lr == LIBUSB_ERROR_NO_DEVICE)
                return gone(u, what);
        if (lr < 0)
                return fail(u, errno_of(lr), "%s: endpoint 0x%02x stalled and clearing the halt failed: %s",
                            what, ep, libusb_error_name(lr));
        return 0;
}

/* One attempt: send the frame, read replies until one carries our sequence number.
 * Returns 0 with the reply in buf, -EAGAIN when the attempt should be repeated (stall
 * cleared, timeout, corrupt reply), or a final negative errno. */
static int attempt(struct usb_dlp *u, const uint8_t *frame, int frame_len, uint8_t *buf, int *ret_len,
                   const char *what) {
        int done = 0;
        int lr = libusb_bulk_transfer(u->h, u->ep_out, (unsigned char *) frame, frame_len, &done, u->timeout_ms);
        if (lr == LIBUSB_ERROR_NO_DEVICE)
                return gone(u, what);
        if (lr == LIBUSB_ERROR_PIPE) {
                int r = clear_halt(u, u->ep_out, what);
                return r < 0 ? r : fail(u, -EAGAIN, "%s: endpoint 0x%02x stalled (halt cleared)", what, u->ep_out);
        }
        if (lr == LIBUSB_ERROR_TIMEOUT)
                return fail(u, -EAGAIN, "%s: sending timed out after %u ms", what, u->timeout_ms);
        if (lr < 0)
                return fail(u, errno_of(lr), "%s: sending: %s", what, libusb_error_name(lr));
        if (done != frame_len)
                return fail(u, -EAGAIN, "%s: device took %d of %d bytes", what, done, frame_len);
        uint16_t seq = get16(frame + 6);
        for (int stale = 0; stale <= USB_DLP_STALE_READS; stale++) {
                int got = 0;
                lr = libusb_bulk_transfer(u->h, u->ep_in, buf, USB_DLP_FRAME_MAX, &got, u->timeout_ms);
                if (lr == LIBUSB_ERROR_NO_DEVICE)
                        return gone(u, what);
                if (lr == LIBUSB_ERROR_PIPE) {
                        int r = clear_halt(u, u->ep_in, what);
                        return r < 0 ? r : fail(u, -EAGAIN, "%s: endpoint 0x%02x stalled (halt cleared)", what,
                                                u->ep_in);
                }
                if (lr == LIBUSB_ERROR_TIMEOUT)
                        return fail(u, -EAGAIN, "%s: no reply within %u ms", what, u->timeout_ms);
                if (lr < 0)
                        return fail(u, errno_of(lr), "%s: receiving: %s", what, libusb_error_name(lr));
                if (got < USB_DLP_HDR_LEN + USB_DLP_CRC_LEN || get16(buf) != USB_DLP_MAGIC)
                        return fail(u, -EAGAIN, "%s: reply of %d bytes is not a frame", what, got);
                unsigned len = get16(buf + 4);
                if (USB_DLP_HDR_LEN + len + USB_DLP_CRC_LEN != (unsigned) got ||
                    crc16(buf, USB_DLP_HDR_LEN + len) != get16(buf + USB_DLP_HDR_LEN + len))
                        return fail(u, -EAGAIN, "%s: reply fails its length or CRC check", what);
                if (get16(buf + 6) != seq)
                        continue;       /* answer to an earlier, abandoned attempt */
                if (buf[2] != (frame[2] | USB_DLP_REPLY))
                        return fail(u, -EPROTO, "%s: reply opcode 0x%02x to opcode 0x%02x", what, buf[2], frame[2]);
                *ret_len = got;
                return 0;
        }
        return fail(u, -EAGAIN, "%s: only stale replies", what);
}

/* Sends one command and waits for its reply; copies at most cap payload bytes into ret
 * (may be NULL) and returns the payload length, or a negative errno with u->error set. */
static int transact(struct usb_dlp *u, uint8_t op, const uint8_t *payload, uint16_t len, uint8_t *ret,
                    size_t cap) {
        char what[48];
        snprintf(what, sizeof what, "%s", op_name(op));
        if (u->gone)
                return fail(u, -ENODEV, "%s: device disconnected earlier", what);
        if (len > USB_DLP_PAYLOAD_MAX)
                return fail(u, -EMSGSIZE, "%s: %u payload bytes", what, len);
        uint8_t frame[USB_DLP_FRAME_MAX], reply[USB_DLP_FRAME_MAX];
        u->seq++;
        put16(frame, USB_DLP_MAGIC);
        frame[2] = op;
        frame[3] = 0;
        put16(frame + 4, len);
        put16(frame + 6, u->seq);
        if (len)
                memcpy(frame + USB_DLP_HDR_LEN, payload, len);
        put16(frame + USB_DLP_HDR_LEN + len, crc16(frame, USB_DLP_HDR_LEN + len));
        int frame_len = USB_DLP_HDR_LEN + len + USB_DLP_CRC_LEN, reply_len = 0, r = -EAGAIN;
        unsigned tries;
        for (tries = 0; tries <= u->retries && r == -EAGAIN; tries++)
                r = attempt(u, frame, frame_len, reply, &reply_len, what);
        if (r == -EAGAIN) {
                /* Keep the last attempt's reason; say that the policy gave up. */
                char last[sizeof u->error];
                snprintf(last, sizeof last, "%s", u->error);
                bool timed_out = strstr(last, "timed out") || strstr(last, "no reply");
                return fail(u, timed_out ? -ETIMEDOUT : -EIO, "%s; gave up after %u attempts", last, tries);
        }
        if (r < 0)
                return r;
        uint8_t st = reply[3];
        if (st != ST_OK)
                return fail(u, status_errno(st), "%s: device answered %s (%u)", what, status_name(st), st);
        unsigned n = get16(reply + 4);
        if (ret)
                memcpy(ret, reply + USB_DLP_HDR_LEN, IMP_MIN((size_t) n, cap));
        u->error[0] = 0;
        return (int) n;
}

static void usb_dlp_close(void *state) {
        struct usb_dlp *u = state;
        if (!u)
                return;
        if (u->claimed && !u->gone)
                (void) libusb_release_interface(u->h, u->iface);
        if (u->h)
                libusb_close(u->h);
        if (u->ctx)
                libusb_exit(u->ctx);
        free(u);
}

struct usb_match {
        bool by_bus;
        unsigned bus, addr;             /* "BBB/DDD", as in /dev/bus/usb/BBB/DDD */
        uint16_t vid, pid;              /* "vvvv:pppp[:serial]" */
        char serial[64];
};

static int parse_match(const char *main, struct usb_match *m) {
        char *end;
        memset(m, 0, sizeof *m);
        if (strchr(main, '/')) {
                unsigned long bus = strtoul(main, &end, 10);
                if (end == main || *end != '/')
                        return -EINVAL;
                const char *a = end + 1;
                unsigned long addr = strtoul(a, &end, 10);
                if (end == a || *end || bus == 0 || bus > 255 || addr == 0 || addr > 127)
                        return -EINVAL;
                m->by_bus = true;
                m->bus = (unsigned) bus;
                m->addr = (unsigned) addr;
                return 0;
        }
        unsigned long vid = strtoul(main, &end, 16);
        if (end - main != 4 || *end != ':')
                return -EINVAL;
        const char *p = end + 1;
        unsigned long pid = strtoul(p, &end, 16);
        if (end - p != 4 || (*end && *end != ':'))
                return -EINVAL;
        m->vid = (uint16_t) vid;
        m->pid = (uint16_t) pid;
        if (*end == ':') {
                if (!end[1] || strlen(end + 1) >= sizeof m->serial)
                        return -EINVAL;
                snprintf(m->serial, sizeof m->serial, "%s", end + 1);
        }
        return 0;
}

/* Opens the first device that matches; -ENODEV when none does. */
static int find_device(struct usb_dlp *u, const struct usb_match *m, const char *main) {
        libusb_device **list = NULL;
        ssize_t n = libusb_get_device_list(u->ctx, &list);
        if (n < 0)
                return fail(u, errno_of((int) n), "listing USB devices: %s", libusb_error_name((int) n));
        int r = -ENODEV, last_open_error = 0;
        for (ssize_t i = 0; i < n && r == -ENODEV; i++) {
                libusb_device *dev = list[i];
                struct libusb_device_descriptor dd;
                if (m->by_bus) {
                        if (libusb_get_bus_number(dev) != m->bus || libusb_get_device_address(dev) != m->addr)
                                continue;
                } else if (libusb_get_device_descriptor(dev, &dd) < 0 || dd.idVendor != m->vid ||
                           dd.idProduct != m->pid)
                        continue;
                libusb_device_handle *h = NULL;
                int lr = libusb_open(dev, &h);
                if (lr < 0) {
                        last_open_error = lr;
                        continue;
                }
                if (m->serial[0]) {
                        char serial[64] = "";
                        if (libusb_get_device_descriptor(dev, &dd) < 0 || !dd.iSerialNumber ||
                            libusb_get_string_descriptor_ascii(h, dd.iSerialNumber, (unsigned char *) serial,
                                                               sizeof serial) < 0 ||
                            strcmp(serial, m->serial) != 0) {
                                libusb_close(h);
                                continue;
                        }
                }
                u->h = h;
                r = 0;
        }
        libusb_free_device_list(list, 1);
        if (r < 0 && last_open_error)
                return fail(u, errno_of(last_open_error), "%s: found but cannot open: %s", main,
                            libusb_error_name(last_open_error));
        if (r < 0)
                return fail(u, r, "%s: no such USB device", main);
        return 0;
}

/* The first vendor-specific interface with one bulk OUT and one bulk IN endpoint. */
static int find_endpoints(struct usb_dlp *u, int want_iface) {
        struct libusb_config_descriptor *cfg = NULL;
        int lr = libusb_get_active_config_descriptor(libusb_get_device(u->h), &cfg);
        if (lr < 0)
                return fail(u, errno_of(lr), "reading the configuration descriptor: %s", libusb_error_name(lr));
        int r = fail(u, -ENXIO, "no vendor-specific interface with bulk IN and OUT endpoints");
        for (int i = 0; i < cfg->bNumInterfaces && r < 0; i++) {
                if (cfg->interface[i].num_altsetting < 1)
                        continue;
                const struct libusb_interface_descriptor *id = &cfg->interface[i].altsetting[0];
                if (id->bInterfaceClass != LIBUSB_CLASS_VENDOR_SPEC ||
                    (want_iface >= 0 && id->bInterfaceNumber != want_iface))
                        continue;
                uint8_t out = 0, in = 0;
                for (int e = 0; e < id->bNumEndpoints; e++) {
                        const struct libusb_endpoint_descriptor *ed = &id->endpoint[e];
                        if ((ed->bmAttributes & LIBUSB_TRANSFER_TYPE_MASK) != LIBUSB_TRANSFER_TYPE_BULK)
                                continue;
                        if (ed->bEndpointAddress & LIBUSB_ENDPOINT_IN) {
                                if (!in)
                                        in = ed->bEndpointAddress;
                        } else if (!out)
                                out = ed->bEndpointAddress;
                }
                if (in && out) {
                        u->iface = id->bInterfaceNumber;
                        u->ep_in = in;
                        u->ep_out = out;
                        r = 0;
                }
        }
        libusb_free_config_descriptor(cfg);
        return r;
}

static int usb_dlp_read_info(struct usb_dlp *u, struct imp_projector_info *ret) {
        uint8_t p[USB_DLP_PAYLOAD_MAX];
        int n = transact(u, OP_GET_INFO, NULL, 0, p, sizeof p);
        if (n < 0)
                return n;
        if (n < 70)
                return fail(u, -EPROTO, "GET_INFO: reply of %d bytes, expected at least 70", n);
        struct imp_projector_info info = { 0 };
        memcpy(info.model, p, 32);
        memcpy(info.serial, p + 32, 32);
        info.model[31] = info.serial[31] = 0;
        info.width = get16(p + 64);
        info.height = get16(p + 66);
        info.max_patterns = IMP_MIN((unsigned) get16(p + 68), (unsigned) IMP_PROJECTOR_MAX_PATTERNS);
        *ret = info;
        return 0;
}

static int usb_dlp_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct usb_dlp *u = calloc(1, sizeof *u);
        if (!u)
                return -ENOMEM;
        char main[128];
        struct usb_match m;
        unsigned iface = UINT_MAX;
        u->timeout_ms = timeout_ms ? timeout_ms : USB_DLP_DEFAULT_TIMEOUT_MS;
        u->retries = USB_DLP_DEFAULT_RETRIES;
        /* Start the sequence where an earlier session is unlikely to have stopped, so the
         * device's reply cache never answers our first command with its last reply. */
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        u->seq = (uint16_t) (ts.tv_nsec ^ (ts.tv_nsec >> 16));
        int r = address_main(address, main, sizeof main);
        if (r >= 0)
                r = parse_match(main, &m);
        if (r >= 0)
                r = address_option_uint(address, "timeout_ms", 1, 600000, &u->timeout_ms);
        if (r >= 0)
                r = address_option_uint(address, "retries", 0, 10, &u->retries);
        if (r >= 0)
                r = address_option_uint(address, "interface", 0, 255, &iface);
        if (r < 0)
                goto fail;
        int lr = libusb_init(&u->ctx);
        if (lr < 0) {
                r = errno_of(lr);
                u->ctx = NULL;
                goto fail;
        }
        r = find_device(u, &m, main);
        if (r >= 0)
                r = find_endpoints(u, iface == UINT_MAX ? -1 : (int) iface);
        if (r < 0)
                goto fail;
        lr = libusb_claim_interface(u->h, u->iface);
        if (lr < 0) {
                r = errno_of(lr);
                goto fail;
        }
        u->claimed = true;
        /* Leftovers from an earlier session (a reply nobody read, a halt) must not be taken
         * for answers: clear both halts and rely on sequence numbers for the rest. */
        (void) libusb_clear_halt(u->h, u->ep_out);
        (void) libusb_clear_halt(u->h, u->ep_in);
        r = usb_dlp_read_info(u, &u->info);
        if (r < 0)
                goto fail;
        *ret_state = u;
        return 0;
fail:
        usb_dlp_close(u);
        return r;
}

static int usb_dlp_get_info(void *state, struct imp_projector_info *ret_info) {
        struct usb_dlp *u = state;
        struct imp_projector_info info;
        int r = usb_dlp_read_info(u, &info);
        if (r < 0)
                return r;
        u->info = info;
        *ret_info = info;
        return 0;
}

/* Wire descriptor of one pattern (docs/projector-usb.md, UPLOAD_PATTERN). */
static int encode_pattern(const struct imp_pattern *p, uint8_t d[USB_DLP_PATTERN_DESC_LEN]) {
        uint8_t kind;
        switch (p->kind) {
        case IMP_PAT_WHITE: kind = 1; break;
        case IMP_PAT_BLACK: kind = 2; break;
        case IMP_PAT_GRAY: kind = 3; break;
        case IMP_PAT_PHASE: kind = 4; break;
        default: return -EINVAL;
        }
        if (p->axis < 0 || p->axis > 1 || p->bit < 0 || p->bit > 255 || p->nbits < 0 || p->nbits > 255 ||
            p->step < 0 || p->step > 65535 || p->steps < 0 || p->steps > 65535 ||
            !(p->period_px >= 0 && p->period_px * 100.0 < 4294967295.0))
                return -EINVAL;
        memset(d, 0, USB_DLP_PATTERN_DESC_LEN);
        d[0] = kind;
        d[1] = (uint8_t) p->axis;
        d[2] = (uint8_t) p->bit;
        d[3] = (uint8_t) p->nbits;
        d[4] = p->inverse ? 1 : 0;
        put16(d + 6, (uint16_t) p->step);
        put16(d + 8, (uint16_t) p->steps);
        put32(d + 10, (uint32_t) (p->period_px * 100.0 + 0.5));
        return 0;
}

static int usb_dlp_upload(void *state, const struct imp_pattern *patterns, unsigned n) {
        struct usb_dlp *u = state;
        if (n == 0 || n > u->info.max_patterns)
                return fail(u, -EINVAL, "upload of %u patterns, device holds 1 to %u", n, u->info.max_patterns);
        uint8_t d[2 + USB_DLP_PATTERN_DESC_LEN];
        for (unsigned i = 0; i < n; i++)
                if (encode_pattern(&patterns[i], d + 2) < 0)
                        return fail(u, -EINVAL, "pattern %u cannot be described on the wire", i);
        put16(d, (uint16_t) n);
        int r = transact(u, OP_UPLOAD_BEGIN, d, 2, NULL, 0);
        for (unsigned i = 0; i < n && r >= 0; i++) {
                put16(d, (uint16_t) i);
                (void) encode_pattern(&patterns[i], d + 2);
                r = transact(u, OP_UPLOAD_PATTERN, d, sizeof d, NULL, 0);
                if (r < 0) {
                        char detail[sizeof u->error];
                        snprintf(detail, sizeof detail, "%s", u->error);
                        return fail(u, r, "pattern %u of %u: %s", i, n, detail);
                }
        }
        if (r >= 0) {
                put16(d, (uint16_t) n);
                r = transact(u, OP_UPLOAD_END, d, 2, NULL, 0);
        }
        return r < 0 ? r : 0;
}

static int usb_dlp_show(void *state, unsigned index) {
        struct usb_dlp *u = state;
        if (index > 65535)
                return fail(u, -EINVAL, "SHOW %u: index out of range", index);
        uint8_t d[2];
        put16(d, (uint16_t) index);
        int r = transact(u, OP_SHOW, d, sizeof d, NULL, 0);
        return r < 0 ? r : 0;
}

static int usb_dlp_dark(void *state) {
        int r = transact(state, OP_DARK, NULL, 0, NULL, 0);
        return r < 0 ? r : 0;
}

static int usb_dlp_trigger(void *state) {
        int r = transact(state, OP_TRIGGER, NULL, 0, NULL, 0);
        return r < 0 ? r : 0;
}

static int usb_dlp_get_status(void *state, struct imp_projector_status *ret_status) {
        struct usb_dlp *u = state;
        uint8_t p[USB_DLP_PAYLOAD_MAX];
        int n = transact(u, OP_GET_STATUS, NULL, 0, p, sizeof p);
        if (n < 0)
                return n;
        if (n < 16)
                return fail(u, -EPROTO, "GET_STATUS: reply of %d bytes, expected at least 16", n);
        *ret_status = (struct imp_projector_status) {
                .shown = (int16_t) get16(p),
                .n_uploaded = get16(p + 2),
                .fault = p[4] != 0,
                .fault_code = get16(p + 6),
                .shown_at_ns = get64(p + 8),
        };
        return 0;
}

static const char *usb_dlp_last_error(void *state) {
        struct usb_dlp *u = state;
        return u->error[0] ? u->error : NULL;
}

const struct imp_projector_ops imp_projector_usb_dlp_ops = {
        .name = "usb-dlp",
        .open = usb_dlp_open,
        .close = usb_dlp_close,
        .get_info = usb_dlp_get_info,
        .upload = usb_dlp_upload,
        .show = usb_dlp_show,
        .dark = usb_dlp_dark,
        .trigger = usb_dlp_trigger,
        .get_status = usb_dlp_get_status,
        .last_error = usb_dlp_last_error,
};
