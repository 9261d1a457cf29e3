/* Modbus TCP or RTU link with impasto's retry policy (modbus-link.h). */
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
        if (l->rtu)
                /* A serial line has no connection to drop a late answer with: discard
                 * whatever the controller sent after we gave up on it. */
                (void) modbus_flush(l->ctx);
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

/* "HOST:PORT" into a TCP context. */
static int new_tcp(struct mb_link *l, const char *main_part) {
        char host[160];
        snprintf(host, sizeof host, "%s", main_part);
        char *colon = strrchr(host, ':');
        if (!colon)
                return -EINVAL;
        *colon = 0;
        char *end;
        long port = strtol(colon + 1, &end, 10);
        if (!colon[1] || *end || port <= 0 || port > 65535 || !host[0])
                return -EINVAL;
        snprintf(l->host, sizeof l->host, "%s:%ld", host, port);
        l->ctx = modbus_new_tcp(host, (int) port);
        return l->ctx ? 0 : -ENOMEM;
}

/* "rtu:DEVICE" and the serial options into an RTU context. */
static int new_rtu(struct mb_link *l, const char *address, const char *device) {
        unsigned baud = MB_LINK_RTU_DEFAULT_BAUD, data_bits = 8, stop_bits = 1;
        char parity[8] = { MB_LINK_RTU_DEFAULT_PARITY };
        int r;
        if (!device[0])
                return -EINVAL;
        if ((r = address_option_uint(address, "baud", 50, 4000000, &baud)) < 0 ||
            (r = address_option_uint(address, "data_bits", 5, 8, &data_bits)) < 0 ||
            (r = address_option_uint(address, "stop_bits", 1, 2, &stop_bits)) < 0)
                return r;
        r = address_option(address, "parity", parity, sizeof parity);
        if (r < 0 && r != -ENOENT)
                return r == -ENAMETOOLONG ? -EINVAL : r;
        if (!strchr("NEO", parity[0]) || !parity[0] || parity[1])
                return -EINVAL;
        l->rtu = true;
        snprintf(l->host, sizeof l->host, "%s%s", MB_LINK_RTU_PREFIX, device);
        l->ctx = modbus_new_rtu(device, (int) baud, parity[0], (int) data_bits, (int) stop_bits);
        return l->ctx ? 0 : -ENOMEM;
}

int mb_link_init(struct mb_link *l, const char *address, unsigned timeout_ms) {
        *l = (struct mb_link) { 0 };
        if (!address)
                return -EINVAL;
        char main_part[160];
        int r = address_main(address, main_part, sizeof main_part);
        if (r < 0)
                return r;
        l->timeout_ms = timeout_ms ? timeout_ms : MB_LINK_DEFAULT_TIMEOUT_MS;
        l->retries = MB_LINK_DEFAULT_RETRIES;
        unsigned unit = 1;
        if ((r = address_option_uint(address, "timeout_ms", 1, 60000, &l->timeout_ms)) < 0 ||
            (r = address_option_uint(address, "retries", 1, 20, &l->retries)) < 0 ||
            (r = address_option_uint(address, "slave", 0, 247, &unit)) < 0 ||
            (r = address_option_uint(address, "unit", 0, 247, &unit)) < 0)
                return r;
        size_t plen = strlen(MB_LINK_RTU_PREFIX);
        r = strncmp(main_part, MB_LINK_RTU_PREFIX, plen) == 0 ? new_rtu(l, address, main_part + plen)
                                                             : new_tcp(l, main_part);
        if (r < 0)
                return r;
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

/* A register write over RTU, its echo checked. A serial line has no transaction id, and
 * libmodbus 3.1.6 accepts any echo with the right function code: the late answer to an
 * earlier write (another register) would pass for this one. The echo names the address and
 * the value (0x06) or the count (0x10); a mismatch is EMBBADDATA, like a garbled frame.
 * Returns what modbus_write_register(s) return, errno set on failure. */
static int rtu_write(struct mb_link *l, int addr, int n, const uint16_t *regs) {
        uint8_t req[7 + 2 * MB_LINK_MAX_WRITE], rsp[MODBUS_RTU_MAX_ADU_LENGTH];
        if (n < 1 || n > MB_LINK_MAX_WRITE) {
                errno = EMBMDATA;
                return -1;
        }
        int len = 0;
        req[len++] = (uint8_t) modbus_get_slave(l->ctx);
        req[len++] = n == 1 ? MODBUS_FC_WRITE_SINGLE_REGISTER : MODBUS_FC_WRITE_MULTIPLE_REGISTERS;
        req[len++] = (uint8_t) (addr >> 8);
        req[len++] = (uint8_t) addr;
        if (n > 1) {
                req[len++] = (uint8_t) (n >> 8);
                req[len++] = (uint8_t) n;
                req[len++] = (uint8_t) (2 * n);
        }
        for (int i = 0; i < n; i++) {
                req[len++] = (uint8_t) (regs[i] >> 8);
                req[len++] = (uint8_t) regs[i];
        }
        if (modbus_send_raw_request(l->ctx, req, len) < 0)
                return -1;
        int rlen = modbus_receive_confirmation(l->ctx, rsp);
        if (rlen < 0)
                return -1;
        /* rsp: unit, function, then the PDU; the CRC was checked by libmodbus. */
        if (rlen >= 3 && rsp[0] == req[0] && rsp[1] == (req[1] | 0x80)) {
                errno = MODBUS_ENOBASE + rsp[2];
                return -1;
        }
        if (rlen < 6 || rsp[0] != req[0] || memcmp(rsp + 1, req + 1, 5) != 0) {
                errno = EMBBADDATA;
                return -1;
        }
        return n;
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
                int rc = write && l->rtu ? rtu_write(l, addr, n, regs) :
                         write ? (n == 1 ? modbus_write_register(l->ctx, addr, regs[0])
                                         : modbus_write_registers(l->ctx, addr, n, regs))
                               : modbus_read_registers(l->ctx, addr, n, regs);
                if (rc == (write && n == 1 && !l->rtu ? 1 : n))
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
