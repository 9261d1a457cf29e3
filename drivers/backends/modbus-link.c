/* Modbus TCP link with impasto's retry policy (modbus-link.h). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "address.h"
#include "macro.h"
#include "modbus-link.h"

#define BACKOFF_FIRST_MS 10
#define BACKOFF_MAX_MS 200

static int link_connect(struct mb_link *l) {
        if (l->connected)
                return 0;
        if (modbus_connect(l->ctx) < 0)
                return negative_errno();
        l->connected = true;
        return 0;
}

static void link_disconnect(struct mb_link *l) {
        if (l->connected)
                modbus_close(l->ctx);
        l->connected = false;
}

static bool is_exception(int e) {
        return e >= EMBXILFUN && e <= EMBXGTAR;
}

int mb_link_init(struct mb_link *l, const char *address, unsigned timeout_ms) {
        *l = (struct mb_link) { 0 };
        if (!address)
                return -EINVAL;
        char main_part[160];
        int r = address_main(address, main_part, sizeof main_part);
        if (r < 0)
                return r;
        char *colon = strrchr(main_part, ':');
        if (!colon)
                return -EINVAL;
        *colon = 0;
        char *end;
        long port = strtol(colon + 1, &end, 10);
        if (!colon[1] || *end || port <= 0 || port > 65535 || !main_part[0])
                return -EINVAL;
        l->timeout_ms = timeout_ms ? timeout_ms : MB_LINK_DEFAULT_TIMEOUT_MS;
        l->retries = MB_LINK_DEFAULT_RETRIES;
        unsigned unit = 1;
        if ((r = address_option_uint(address, "timeout_ms", 1, 60000, &l->timeout_ms)) < 0 ||
            (r = address_option_uint(address, "retries", 1, 20, &l->retries)) < 0 ||
            (r = address_option_uint(address, "unit", 0, 247, &unit)) < 0)
                return r;
        snprintf(l->host, sizeof l->host, "%s:%ld", main_part, port);
        l->ctx = modbus_new_tcp(main_part, (int) port);
        if (!l->ctx)
                return -ENOMEM;
        modbus_set_slave(l->ctx, (int) unit);
        modbus_set_error_recovery(l->ctx, MODBUS_ERROR_RECOVERY_NONE);   /* ours is bounded */
        modbus_set_response_timeout(l->ctx, l->timeout_ms / 1000, (l->timeout_ms % 1000) * 1000);
        return 0;
}

void mb_link_close(struct mb_link *l) {
        if (!l || !l->ctx)
                return;
        link_disconnect(l);
        modbus_free(l->ctx);
        l->ctx = NULL;
}

int mb_link_xfer(struct mb_link *l, bool write, int addr, int n, uint16_t *regs) {
        unsigned backoff_ms = BACKOFF_FIRST_MS;
        int r = -EIO;
        for (unsigned attempt = 0; attempt < l->retries; attempt++) {
                if (attempt > 0) {
                        usleep(backoff_ms * 1000u);
                        backoff_ms = IMP_MIN(backoff_ms * 2, BACKOFF_MAX_MS);
                }
                r = link_connect(l);
                if (r < 0) {
                        snprintf(l->error, sizeof l->error, "connect %s (attempt %u of %u): %s",
                                 l->host, attempt + 1, l->retries, modbus_strerror(-r));
                        continue;
                }
                int rc = write ? (n == 1 ? modbus_write_register(l->ctx, addr, regs[0])
                                         : modbus_write_registers(l->ctx, addr, n, regs))
                               : modbus_read_registers(l->ctx, addr, n, regs);
                if (rc == (write && n == 1 ? 1 : n))
                        return 0;
                int e = rc < 0 ? errno : EMBBADDATA;
                snprintf(l->error, sizeof l->error, "%s %d register%s at 0x%04x (attempt %u of %u): %s%s",
                         write ? "write" : "read", n, n == 1 ? "" : "s", (unsigned) addr, attempt + 1,
                         l->retries, modbus_strerror(e), is_exception(e) ? " (Modbus exception)" : "");
                if (is_exception(e) && e != EMBXSBUSY)
                        return -EIO;            /* the controller said no: asking again will not help */
                /* Transport trouble: a fresh connection also drops any late answer. */
                link_disconnect(l);
                r = e == ETIMEDOUT ? -ETIMEDOUT : e == ECONNRESET || e == EPIPE ? -ECONNRESET :
                    is_exception(e) ? -EBUSY : -EIO;
        }
        return r;
}
