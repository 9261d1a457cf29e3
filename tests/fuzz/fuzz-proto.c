/* Target 1: the control protocol (proto/linebuf.c, proto/protocol.c) as the daemon and the
 * client meet it. The first byte picks the peer's role and the chunk size of the reads; the
 * rest is the byte stream of a connection, split by imp_linebuf into lines, each parsed as a
 * request (daemon side) and as a daemon message (client side). Checked: no line longer than
 * the limit, memory bounded by limit plus one read, every refusal has a code and a message,
 * and the error reply the daemon would send is one line the client parses back to the same
 * code and field. */
#include <errno.h>
#include <string.h>
#include "fuzz.h"
#include "protocol.h"

#define LINE_MAX_FUZZ 4096   /* a small limit, so that the fuzzer reaches the oversized path */

static void check_error_reply(const struct imp_proto_error *e) {
        FUZZ_CHECK(e->code != IMP_PROTO_E_NONE, "a refused request without an error code");
        FUZZ_CHECK(e->message[0], "a refused request (%s) without a message", imp_proto_error_code_name(e->code));
        json_t *reply = imp_proto_reply_error(NULL, e);
        FUZZ_CHECK(reply, "no error reply for \"%s\"", e->message);
        char *line = imp_proto_dump_line(reply);
        json_decref(reply);
        FUZZ_CHECK(line, "error reply not dumped");
        size_t n = strlen(line);
        FUZZ_CHECK(n > 1 && line[n - 1] == '\n' && !memchr(line, '\n', n - 1), "error reply is not one line");
        struct imp_proto_message m = {};
        struct imp_proto_error pe = {};
        int r = imp_proto_parse_reply(line, n - 1, &m, &pe);
        FUZZ_CHECK(r == 0, "the client cannot parse the daemon's error reply %s: %s", line, pe.message);
        FUZZ_CHECK(m.kind == IMP_PROTO_MSG_REPLY && !m.ok && m.error.code == e->code,
                   "error reply decoded to another code: %s", line);
        FUZZ_CHECK(strlen(m.error.field) == strlen(e->field), "field changed on the way: %s", line);
        imp_proto_message_done(&m);
        imp_proto_error_done(&pe);
        free(line);
}

static void one_request(const char *line, size_t len, enum imp_proto_role role) {
        struct imp_proto_request req = {};
        struct imp_proto_error e = {};
        int r = imp_proto_parse_request(line, len, role, &req, &e);
        if (r == 0) {
                FUZZ_CHECK(req.command && json_is_object(req.args), "accepted request without command or args");
                FUZZ_CHECK(json_is_integer(req.id) || json_is_string(req.id), "accepted request with a bad id");
                FUZZ_CHECK(!req.command->operator_only || role == IMP_PROTO_ROLE_OPERATOR,
                           "observer may run %s", req.command->name);
                imp_proto_request_done(&req);
        } else {
                FUZZ_CHECK(r == -E2BIG || r == -EBADMSG || r == -EINVAL || r == -EOPNOTSUPP || r == -EPERM ||
                           r == -ENOMEM, "unexpected return %d", r);
                check_error_reply(&e);
        }
        imp_proto_error_done(&e);
}

static void one_message(const char *line, size_t len) {
        struct imp_proto_message m = {};
        struct imp_proto_error e = {};
        int r = imp_proto_parse_reply(line, len, &m, &e);
        if (r == 0) {
                FUZZ_CHECK(json_is_object(m.root), "message without root");
                if (m.kind == IMP_PROTO_MSG_REPLY && !m.ok)
                        FUZZ_CHECK(memchr(m.error.message, 0, sizeof m.error.message), "unterminated message");
                imp_proto_message_done(&m);
        } else {
                FUZZ_CHECK(r == -E2BIG || r == -EBADMSG || r == -ENOMEM, "unexpected return %d", r);
                FUZZ_CHECK(e.code != IMP_PROTO_E_NONE && e.message[0], "refused message without a reason");
        }
        imp_proto_error_done(&e);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        if (size < 1)
                return 0;
        enum imp_proto_role role = data[0] & 1 ? IMP_PROTO_ROLE_OPERATOR : IMP_PROTO_ROLE_OBSERVER;
        size_t chunk = 1 + (data[0] >> 1) * 37;   /* 1 .. 4718 bytes per read */
        data++, size--;

        /* one whole input as one line, at the real limits */
        one_request((const char *) data, size, role);
        one_message((const char *) data, size);

        /* the same bytes as a stream */
        struct imp_linebuf *lb = NULL;
        FUZZ_CHECK(imp_linebuf_new(LINE_MAX_FUZZ, &lb) == 0, "linebuf_new");
        for (size_t off = 0; off < size; off += chunk) {
                size_t n = size - off < chunk ? size - off : chunk;
                FUZZ_CHECK(imp_linebuf_feed(lb, data + off, n) == 0, "feed");
                for (;;) {
                        char *line;
                        size_t len;
                        int r = imp_linebuf_next(lb, &line, &len);
                        if (r == 0)
                                break;
                        if (r == -E2BIG)
                                continue;
                        FUZZ_CHECK(r == 1, "linebuf_next returned %d", r);
                        FUZZ_CHECK(len >= 1 && len <= LINE_MAX_FUZZ && line[len] == '\0' && !memchr(line, '\n', len),
                                   "bad line of %zu bytes", len);
                        one_request(line, len, role);
                        one_message(line, len);
                }
                FUZZ_CHECK(imp_linebuf_pending(lb) <= LINE_MAX_FUZZ + chunk, "linebuf holds %zu bytes",
                           imp_linebuf_pending(lb));
        }
        imp_linebuf_free(lb);
        return 0;
}
