/* A Modbus link, TCP or RTU, with impasto's client policy (docs/dome-registers.md, "Client
 * policy"): address "HOST:PORT[;options]" or "rtu:DEVICE[;baud=N][;parity=N|E|O]
 * [;data_bits=N][;stop_bits=N][;options]", options timeout_ms, retries and unit (alias
 * slave); a response timeout per request, bounded retries with doubling backoff and a fresh
 * connection (RTU: the port reopened and its input flushed) after any transport error,
 * exceptions not retried (except 0x06 server busy). Shared by the Modbus backends. */
#pragma once
#include <modbus.h>
#include <stdbool.h>
#include <stdint.h>

#define MB_LINK_DEFAULT_TIMEOUT_MS 200
#define MB_LINK_DEFAULT_RETRIES 3               /* attempts in all */
#define MB_LINK_MAX_WRITE 120                   /* registers per write request we send */
#define MB_LINK_MAX_READ 120
#define MB_LINK_RTU_PREFIX "rtu:"
#define MB_LINK_RTU_DEFAULT_BAUD 19200          /* the Modbus serial line defaults: 19200 8E1 */
#define MB_LINK_RTU_DEFAULT_PARITY 'E'

struct mb_link {
        modbus_t *ctx;
        bool connected;
        bool rtu;                               /* serial line: flush after every (re)open */
        unsigned timeout_ms, retries;
        char host[192];                         /* "HOST:PORT" or "rtu:DEVICE", for messages */
        char error[384];
};

/* Parses the address and creates the context (no connection yet). -EINVAL for a bad
 * address or option, -ENOMEM. On failure the link is left closed (mb_link_close is safe). */
int mb_link_init(struct mb_link *l, const char *address, unsigned timeout_ms);
void mb_link_close(struct mb_link *l);
/* One transfer under the policy. write: n registers from regs at addr; read: into regs.
 * -EIO for an exception (named in l->error), -ETIMEDOUT, -ECONNRESET, -EBUSY, -EIO. */
int mb_link_xfer(struct mb_link *l, bool write, int addr, int n, uint16_t *regs);
static inline int mb_link_write1(struct mb_link *l, int addr, uint16_t v) {
        return mb_link_xfer(l, true, addr, 1, &v);
}
