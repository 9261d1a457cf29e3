/* gpiochip emulator: a umockdev testbed /dev/gpiochipN whose ioctls (GPIO character device
 * uAPI v1, which libgpiod 1.6 uses) are answered here: chip info, line info, line handle
 * requests, handle get/set values. It records each line's physical level, so the dome's
 * state is known, and can report a line busy or fail a set.
 *
 * Line handles: GPIO_GET_LINEHANDLE_IOCTL must return a new fd whose ioctls reach this
 * handler too. umockdev only forwards ioctls on fds it opened itself, so the emulator opens
 * a small pool of extra /dev/gpiochipN fds up front (in the caller's thread), introduces
 * each to the handler with a private ioctl, and hands one out per handle request. */
#include <fcntl.h>
#include <linux/gpio.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <umockdev.h>
#include <unistd.h>
#include "emu.h"

#define MAX_LINES 64
#define HANDLE_POOL 8
#define EMU_HELLO_IOCTL _IOW(0xB4, 0x7E, uint32_t)     /* private: "this fd is pool slot n" */
#define CLIENT_KEY "imp-emu-gpio-slot"

struct line {
        int handle;             /* pool slot holding it, -1 free */
        bool busy;              /* held by "another consumer" */
        bool active_low;
        int level;              /* physical, -1 not driven */
        char consumer[GPIO_MAX_NAME_SIZE];
};

struct handle {
        bool in_use;
        bool given;             /* its fd went to a client: that fd is theirs to close */
        int fd;
        dev_t st_dev;           /* identity of fd, to notice it closed and its number reused */
        ino_t st_ino;
        unsigned n;
        unsigned offsets[GPIOHANDLES_MAX];
        bool active_low;
};

struct imp_emu_gpio {
        struct imp_emu_gpio_config cfg;
        char devnode[64];
        struct imp_emu_rig *rig;
        UMockdevTestbed *tb;
        UMockdevIoctlBase *handler;
        pthread_mutex_t lock;
        struct line lines[MAX_LINES];
        struct handle handles[HANDLE_POOL];
        unsigned fail_countdown;
        int fail_errno;
        unsigned n_set_calls;
};

/* umockdev_in_mock_environment() decides by stat("/sys") and caches its first answer,
 * which is "no" until a testbed exists; so look for the preload library in our own map. */
bool imp_emu_gpio_available(void) {
        FILE *f = fopen("/proc/self/maps", "re");
        if (!f)
                return false;
        char line[512];
        bool found = false;
        while (!found && fgets(line, sizeof line, f))
                found = strstr(line, "libumockdev-preload") != NULL;
        fclose(f);
        return found;
}

static void publish_led_locked(struct imp_emu_gpio *e, unsigned line) {
        if (line < e->cfg.light_line_base || line >= e->cfg.light_line_base + e->cfg.n_lights)
                return;
        int lv = e->lines[line].level;
        bool lit = lv >= 0 && (e->cfg.leds_active_low ? lv == 0 : lv == 1);
        imp_emu_rig_set_light(e->rig, line - e->cfg.light_line_base, lit ? 1000 : 0);
}

static int slot_of(UMockdevIoctlClient *client) {
        return GPOINTER_TO_INT(g_object_get_data(G_OBJECT(client), CLIENT_KEY)) - 1;
}

/* Each handler returns an errno (0 = success) after filling the resolved argument. */
static int do_chipinfo(struct imp_emu_gpio *e, UMockdevIoctlData *arg) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct gpiochip_info), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        struct gpiochip_info *ci = (struct gpiochip_info *) d->data;
        memset(ci, 0, sizeof *ci);
        snprintf(ci->name, sizeof ci->name, "%s", e->cfg.chip_name);
        snprintf(ci->label, sizeof ci->label, "%s", e->cfg.label);
        ci->lines = e->cfg.n_lines;
        return 0;
}

static int do_lineinfo(struct imp_emu_gpio *e, UMockdevIoctlData *arg) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct gpioline_info), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        struct gpioline_info *li = (struct gpioline_info *) d->data;
        unsigned off = li->line_offset;
        if (off >= e->cfg.n_lines)
                return EINVAL;
        const struct line *l = &e->lines[off];
        memset(li, 0, sizeof *li);
        li->line_offset = off;
        snprintf(li->name, sizeof li->name, "LED%u", off);
        if (l->busy || l->handle >= 0) {
                li->flags |= GPIOLINE_FLAG_KERNEL | GPIOLINE_FLAG_IS_OUT;
                snprintf(li->consumer, sizeof li->consumer, "%s", l->consumer);
        }
        if (l->active_low)
                li->flags |= GPIOLINE_FLAG_ACTIVE_LOW;
        return 0;
}

static int do_linehandle(struct imp_emu_gpio *e, UMockdevIoctlData *arg) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct gpiohandle_request), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        struct gpiohandle_request *req = (struct gpiohandle_request *) d->data;
        if (req->lines == 0 || req->lines > GPIOHANDLES_MAX)
                return EINVAL;
        for (unsigned i = 0; i < req->lines; i++) {
                if (req->lineoffsets[i] >= e->cfg.n_lines)
                        return EINVAL;
                const struct line *l = &e->lines[req->lineoffsets[i]];
                if (l->busy || l->handle >= 0)
                        return EBUSY;
        }
        int slot = -1;
        for (int s = 0; s < HANDLE_POOL; s++)
                if (!e->handles[s].in_use && !e->handles[s].given && e->handles[s].fd >= 0) {
                        slot = s;
                        break;
                }
        if (slot < 0)
                return EMFILE;
        struct handle *h = &e->handles[slot];
        h->in_use = h->given = true;
        h->n = req->lines;
        h->active_low = req->flags & GPIOHANDLE_REQUEST_ACTIVE_LOW;
        bool output = req->flags & GPIOHANDLE_REQUEST_OUTPUT;
        for (unsigned i = 0; i < req->lines; i++) {
                unsigned off = req->lineoffsets[i];
                h->offsets[i] = off;
                struct line *l = &e->lines[off];
                l->handle = slot;
                l->active_low = h->active_low;
                snprintf(l->consumer, sizeof l->consumer, "%s", req->consumer_label);
                if (output) {
                        l->level = (req->default_values[i] ? 1 : 0) ^ (h->active_low ? 1 : 0);
                        publish_led_locked(e, off);
                }
        }
        req->fd = h->fd;
        return 0;
}

static int do_values(struct imp_emu_gpio *e, UMockdevIoctlClient *client, UMockdevIoctlData *arg, bool set) {
        int slot = slot_of(client);
        if (slot < 0 || !e->handles[slot].in_use)
                return EBADF;
        struct handle *h = &e->handles[slot];
        if (set) {
                e->n_set_calls++;
                if (e->fail_countdown && --e->fail_countdown == 0)
                        return e->fail_errno;
        }
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct gpiohandle_data), &err);
        if (!d) {
                g_clear_error(&err);
                return EFAULT;
        }
        struct gpiohandle_data *v = (struct gpiohandle_data *) d->data;
        for (unsigned i = 0; i < h->n; i++) {
                struct line *l = &e->lines[h->offsets[i]];
                if (set) {
                        l->level = (v->values[i] ? 1 : 0) ^ (h->active_low ? 1 : 0);
                        publish_led_locked(e, h->offsets[i]);
                } else
                        v->values[i] = (uint8_t) ((l->level > 0 ? 1 : 0) ^ (h->active_low ? 1 : 0));
        }
        return 0;
}

/* A handle's fd was closed by its owner: its lines are free and no longer driven.
 * umockdev 0.17 emits no "client-vanished" when a forwarded fd is closed, so the emulator
 * checks its handles' fds itself (they live in this process) before answering anything. */
static void reap_locked(struct imp_emu_gpio *e) {
        for (int s = 0; s < HANDLE_POOL; s++) {
                struct handle *h = &e->handles[s];
                if (!h->in_use)
                        continue;
                struct stat st;
                if (fstat(h->fd, &st) == 0 && st.st_dev == h->st_dev && st.st_ino == h->st_ino)
                        continue;
                for (unsigned i = 0; i < h->n; i++) {
                        struct line *l = &e->lines[h->offsets[i]];
                        l->handle = -1;
                        l->level = -1;
                        l->consumer[0] = 0;
                        publish_led_locked(e, h->offsets[i]);
                }
                h->in_use = false;
        }
}

static gboolean on_ioctl(UMockdevIoctlBase *handler, UMockdevIoctlClient *client, gpointer data) {
        struct imp_emu_gpio *e = data;
        gulong request = umockdev_ioctl_client_get_request(client);
        UMockdevIoctlData *arg = umockdev_ioctl_client_get_arg(client);
        int err = 0;
        pthread_mutex_lock(&e->lock);
        reap_locked(e);
        switch (request) {
        case EMU_HELLO_IOCTL: {
                GError *gerr = NULL;
                UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(uint32_t), &gerr);
                if (!d) {
                        g_clear_error(&gerr);
                        err = EFAULT;
                        break;
                }
                uint32_t slot = *(uint32_t *) d->data;
                g_object_set_data(G_OBJECT(client), CLIENT_KEY, GINT_TO_POINTER((int) slot + 1));
                break;
        }
        case GPIO_GET_CHIPINFO_IOCTL: err = do_chipinfo(e, arg); break;
        case GPIO_GET_LINEINFO_IOCTL: err = do_lineinfo(e, arg); break;
        case GPIO_GET_LINEHANDLE_IOCTL: err = do_linehandle(e, arg); break;
        case GPIOHANDLE_SET_LINE_VALUES_IOCTL: err = do_values(e, client, arg, true); break;
        case GPIOHANDLE_GET_LINE_VALUES_IOCTL: err = do_values(e, client, arg, false); break;
        default: err = ENOTTY; break;
        }
        pthread_mutex_unlock(&e->lock);
        umockdev_ioctl_client_complete(client, err ? -1 : 0, err);
        return TRUE;
}

int imp_emu_gpio_new(const struct imp_emu_gpio_config *cfg, struct imp_emu_rig *rig,
                     struct imp_emu_gpio **ret_emu) {
        if (!cfg || !ret_emu)
                return -EINVAL;
        if (!imp_emu_gpio_available())
                return -ENOTSUP;
        struct imp_emu_gpio *e = calloc(1, sizeof *e);
        if (!e)
                return -ENOMEM;
        e->cfg = *cfg;
        if (!e->cfg.chip_name)
                e->cfg.chip_name = "gpiochip0";
        if (!e->cfg.label)
                e->cfg.label = "impasto-dome";
        if (!e->cfg.n_lines)
                e->cfg.n_lines = 16;
        if (!e->cfg.n_lights && e->cfg.light_line_base < e->cfg.n_lines)
                e->cfg.n_lights = e->cfg.n_lines - e->cfg.light_line_base;
        e->rig = rig;
        pthread_mutex_init(&e->lock, NULL);
        for (unsigned i = 0; i < MAX_LINES; i++) {
                e->lines[i].handle = -1;
                e->lines[i].level = -1;
        }
        for (int s = 0; s < HANDLE_POOL; s++)
                e->handles[s].fd = -1;
        int r = -EINVAL;
        if (e->cfg.n_lines > MAX_LINES || e->cfg.light_line_base + e->cfg.n_lights > e->cfg.n_lines ||
            strlen(e->cfg.chip_name) > 32)
                goto fail;
        snprintf(e->devnode, sizeof e->devnode, "/dev/%s", e->cfg.chip_name);

        e->tb = umockdev_testbed_new();
        char record[512];
        /* The sysfs "dev" attribute needs its trailing newline (\n escaped in the record
         * format): libgpiod compares it with the node's major:minor. */
        snprintf(record, sizeof record,
                 "P: /devices/platform/gpio-emu.0/%s\nN: %s\nE: SUBSYSTEM=gpio\nE: DEVNAME=%s\nA: dev=254:0\\n\n",
                 e->cfg.chip_name, e->cfg.chip_name, e->devnode);
        GError *err = NULL;
        r = -EIO;
        if (!umockdev_testbed_add_from_string(e->tb, record, &err))
                goto fail_gerror;
        e->handler = umockdev_ioctl_base_new();
        g_signal_connect(e->handler, "handle-ioctl", G_CALLBACK(on_ioctl), e);
        if (!umockdev_testbed_attach_ioctl(e->tb, e->devnode, e->handler, &err))
                goto fail_gerror;
        for (int s = 0; s < HANDLE_POOL; s++) {
                e->handles[s].fd = open(e->devnode, O_RDWR | O_CLOEXEC);
                uint32_t slot = (uint32_t) s;
                struct stat st;
                if (e->handles[s].fd < 0 || ioctl(e->handles[s].fd, EMU_HELLO_IOCTL, &slot) < 0 ||
                    fstat(e->handles[s].fd, &st) < 0) {
                        r = negative_errno();
                        goto fail;
                }
                e->handles[s].st_dev = st.st_dev;
                e->handles[s].st_ino = st.st_ino;
        }
        *ret_emu = e;
        return 0;
fail_gerror:
        g_clear_error(&err);
fail:
        imp_emu_gpio_free(e);
        return r;
}

void imp_emu_gpio_free(struct imp_emu_gpio *e) {
        if (!e)
                return;
        for (int s = 0; s < HANDLE_POOL; s++)
                if (e->handles[s].fd >= 0 && !e->handles[s].given)
                        close(e->handles[s].fd);
        if (e->tb && e->handler)
                umockdev_testbed_detach_ioctl(e->tb, e->devnode, NULL);
        g_clear_object(&e->handler);
        g_clear_object(&e->tb);
        pthread_mutex_destroy(&e->lock);
        free(e);
}

int imp_emu_gpio_line_level(struct imp_emu_gpio *e, unsigned line) {
        if (!e || line >= e->cfg.n_lines)
                return -1;
        pthread_mutex_lock(&e->lock);
        reap_locked(e);
        int lv = e->lines[line].level;
        pthread_mutex_unlock(&e->lock);
        return lv;
}

void imp_emu_gpio_set_busy(struct imp_emu_gpio *e, unsigned line, bool busy) {
        if (!e || line >= e->cfg.n_lines)
                return;
        pthread_mutex_lock(&e->lock);
        e->lines[line].busy = busy;
        snprintf(e->lines[line].consumer, sizeof e->lines[line].consumer, "%s", busy ? "other-daemon" : "");
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_gpio_fail_set_nth(struct imp_emu_gpio *e, unsigned nth, int err) {
        pthread_mutex_lock(&e->lock);
        e->fail_countdown = nth;
        e->fail_errno = err;
        pthread_mutex_unlock(&e->lock);
}

unsigned imp_emu_gpio_n_set_calls(struct imp_emu_gpio *e) {
        pthread_mutex_lock(&e->lock);
        unsigned n = e->n_set_calls;
        pthread_mutex_unlock(&e->lock);
        return n;
}
