/* Hostile input to the control protocol: seeded random bytes, truncated JSON, deep nesting,
 * huge numbers, NUL bytes, invalid UTF-8, 70 KiB lines and wrong types for every field. Each
 * message goes through one long-lived line splitter in random chunks, followed by a valid
 * probe request: every hostile line must get exactly one well-formed error reply, and the
 * probe after it an ok reply. Run under ASan for crashes and leaks. */
#include <errno.h>
#include <string.h>
#include "json-util.h"
#include "protocol.h"
#include "test.h"

static unsigned long long rng = 0x1badc0ffee;
static unsigned rnd(unsigned n) {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        return (unsigned) (rng >> 33) % n;
}

/* The server side as impastod runs it: splitter → parser → reply line. */
static struct imp_linebuf *server_lb;
static int cases, replies_checked;

struct reply_log {
        int n;
        json_t *msgs[8];
};

static void reply_line(struct reply_log *log, json_t *reply) {
        _cleanup_free_ char *line = imp_proto_dump_line(reply);
        json_decref(reply);
        CHECK(line);
        if (!line)
                return;
        size_t len = strlen(line);
        CHECK(len > 1 && len <= IMP_PROTO_MESSAGE_MAX && strchr(line, '\n') == line + len - 1);
        /* the client parses what the server wrote */
        struct imp_proto_message m = {};
        _cleanup_proto_error_ struct imp_proto_error e = {};
        int r = imp_proto_parse_reply(line, len - 1, &m, &e);
        CHECK_MSG(r == 0, "client cannot parse %s: %s", line, e.message);
        if (r < 0)
                return;
        CHECK_INT_EQ(m.kind, IMP_PROTO_MSG_REPLY);
        replies_checked++;
        if (log->n < (int) ARRAY_SIZE(log->msgs))
                log->msgs[log->n++] = json_incref(m.root);
        else
                log->n++;
        imp_proto_message_done(&m);
}

static void serve_line(struct reply_log *log, const char *line, size_t len, enum imp_proto_role role) {
        _cleanup_proto_request_ struct imp_proto_request req = {};
        _cleanup_proto_error_ struct imp_proto_error e = {};
        int r = imp_proto_parse_request(line, len, role, &req, &e);
        if (r < 0) {
                CHECK_MSG(e.code >= IMP_PROTO_E_TOO_LONG && e.code <= IMP_PROTO_E_PERMISSION_DENIED,
                          "code %d for a request", e.code);
                reply_line(log, imp_proto_reply_error(NULL, &e));
        } else
                reply_line(log, imp_proto_reply_ok(req.id, json_pack("{s:s}", "cmd", req.command->name)));
}

static void serve_bytes(struct reply_log *log, const char *data, size_t n, enum imp_proto_role role) {
        for (size_t at = 0; at < n;) {
                size_t k = rnd(3) == 0 ? 1 + rnd(8) : 1 + rnd(9000);
                k = IMP_MIN(k, n - at);
                CHECK_OK(imp_linebuf_feed(server_lb, data + at, k));
                at += k;
                char *line;
                size_t len;
                int r;
                while ((r = imp_linebuf_next(server_lb, &line, &len)) != 0) {
                        if (r == -E2BIG) {
                                struct imp_proto_error e = {};
                                imp_proto_error_set(&e, IMP_PROTO_E_TOO_LONG, E2BIG, NULL,
                                                    "line longer than %d bytes", IMP_PROTO_REQUEST_MAX);
                                reply_line(log, imp_proto_reply_error(NULL, &e));
                        } else {
                                CHECK_INT_EQ(r, 1);
                                serve_line(log, line, len, role);
                        }
                }
        }
}

/* One hostile message (no '\n' inside; a '\n' is appended), then a probe. */
static void hostile(const char *msg, size_t n, enum imp_proto_role role, enum imp_proto_errcode want,
                    const char *want_field) {
        cases++;
        char probe[64];
        int pn = snprintf(probe, sizeof probe, "{\"id\":\"probe-%d\",\"cmd\":\"status\"}\n", cases);
        char *buf = malloc(n + 1 + (size_t) pn);
        memcpy(buf, msg, n);
        for (size_t i = 0; i < n; i++)
                if (buf[i] == '\n')
                        buf[i] = ' ';
        buf[n] = '\n';
        memcpy(buf + n + 1, probe, (size_t) pn);

        struct reply_log log = {};
        serve_bytes(&log, buf, n + 1 + (size_t) pn, role);
        free(buf);

        CHECK_MSG(log.n == 2, "case %d (%.60s…): %d replies", cases, msg, log.n);
        if (log.n >= 1) {
                json_t *err = json_object_get(log.msgs[0], "error");
                CHECK_MSG(json_is_false(json_object_get(log.msgs[0], "ok")), "case %d (%.60s…) accepted", cases, msg);
                const char *code = json_string_value(json_object_get(err, "code"));
                if (want != IMP_PROTO_E_NONE)
                        CHECK_MSG(code && !strcmp(code, imp_proto_error_code_name(want)),
                                  "case %d (%.80s): code %s, expected %s", cases, msg, code,
                                  imp_proto_error_code_name(want));
                if (want_field)
                        CHECK_STR_EQ(json_string_value(json_object_get(err, "field")), want_field);
                CHECK(json_is_string(json_object_get(err, "message")));
                CHECK(json_integer_value(json_object_get(err, "errno")) > 0);
        }
        if (log.n >= 2) {
                char id[32];
                snprintf(id, sizeof id, "probe-%d", cases);
                CHECK(json_is_true(json_object_get(log.msgs[1], "ok")));
                CHECK_STR_EQ(json_string_value(json_object_get(log.msgs[1], "id")), id);
        }
        for (int i = 0; i < log.n && i < (int) ARRAY_SIZE(log.msgs); i++)
                json_decref(log.msgs[i]);

        /* the same bytes handed to the client-side parser: an error, never a crash */
        struct imp_proto_message m = {};
        _cleanup_proto_error_ struct imp_proto_error e = {};
        if (imp_proto_parse_reply(msg, n, &m, &e) == 0)
                imp_proto_message_done(&m);
        else
                CHECK(!m.root && e.message[0]);
}

static void hostile_str(const char *msg, enum imp_proto_errcode want, const char *field) {
        hostile(msg, strlen(msg), IMP_PROTO_ROLE_OPERATOR, want, field);
}

static void random_bytes(void) {
        char buf[256];
        for (int i = 0; i < 300; i++) {
                size_t n = 1 + rnd(sizeof buf);
                for (size_t k = 0; k < n; k++)
                        buf[k] = (char) rnd(256);
                if (n == 1 && buf[0] == '\r')
                        buf[0] = 'x';           /* a lone CR is a blank line, not a message */
                /* any request-level code may come out; printable starts exercise the lexer */
                if (i % 2)
                        buf[0] = "{[\"0-tfn "[rnd(9)];
                hostile(buf, n, rnd(2) ? IMP_PROTO_ROLE_OPERATOR : IMP_PROTO_ROLE_OBSERVER, IMP_PROTO_E_NONE, NULL);
        }
}

static const char *const valid[] = {
        "{\"id\":1,\"cmd\":\"status\"}",
        "{\"id\":\"a-b\",\"cmd\":\"session.start\",\"args\":{\"plan\":\"/plans/x.json\",\"name\":\"nw\"}}",
        "{\"id\":3,\"cmd\":\"calibrate\",\"args\":{\"routine\":\"lights\",\"args\":{\"k\":[1,2,{\"z\":null}]}}}",
        "{\"id\":4,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"progress\",\"frame\",\"fault\"]}}",
        "{\"id\":5,\"cmd\":\"session.list\",\"args\":{\"limit\":50}}",
        "{\"id\":\"caf\xc3\xa9\",\"cmd\":\"jobs.retry\",\"args\":{\"job\":\"j-1\"}}",
};

static void truncated(void) {
        for (size_t v = 0; v < ARRAY_SIZE(valid); v++)
                for (size_t n = 1; n < strlen(valid[v]); n++)   /* some cut inside "é" */
                        hostile(valid[v], n, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_BAD_JSON, NULL);
}

static void deep(void) {
        static const char *const opens[] = { "[", "{\"a\":", "[{\"a\":", "{\"id\":1,\"cmd\":\"status\",\"args\":{\"x\":" };
        for (size_t o = 0; o < ARRAY_SIZE(opens); o++)
                for (int depth = 33; depth <= 10000; depth = depth < 100 ? depth + 67 : depth * 10) {
                        size_t ol = strlen(opens[o]);
                        char *buf = malloc(ol * (size_t) depth + 1);
                        for (int i = 0; i < depth; i++)
                                memcpy(buf + ol * (size_t) i, opens[o], ol);
                        size_t n = ol * (size_t) depth;
                        hostile(buf, n, IMP_PROTO_ROLE_OPERATOR,
                                n > IMP_PROTO_REQUEST_MAX ? IMP_PROTO_E_TOO_LONG : IMP_PROTO_E_BAD_JSON, NULL);
                        free(buf);
                }
        /* balanced and deep: 10,000 '[' then 10,000 ']' */
        char *buf = malloc(20000);
        memset(buf, '[', 10000);
        memset(buf + 10000, ']', 10000);
        hostile(buf, 20000, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_BAD_JSON, NULL);
        free(buf);
        /* unbalanced closers do not underflow anything */
        hostile_str("]]]]]]]]]]}}}}}}}}}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":1,\"cmd\":\"status\"}]]]]]", IMP_PROTO_E_BAD_JSON, NULL);
}

static void numbers(void) {
        hostile_str("{\"id\":1e999,\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":-1e400,\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":99999999999999999999999999,\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":1e300,\"cmd\":\"status\"}", IMP_PROTO_E_BAD_REQUEST, "id");
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":9223372036854775807}}",
                    IMP_PROTO_E_BAD_ARGUMENT, "args.limit");
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":-9223372036854775808}}",
                    IMP_PROTO_E_BAD_ARGUMENT, "args.limit");
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":9223372036854775808}}",
                    IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":1e308}}", IMP_PROTO_E_BAD_ARGUMENT,
                    "args.limit");
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":NaN}}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":Infinity}}", IMP_PROTO_E_BAD_JSON, NULL);
        /* a number of 60,000 digits */
        size_t n = 60000;
        char *buf = malloc(n + 64);
        int k = sprintf(buf, "{\"id\":");
        memset(buf + k, '7', n);
        strcpy(buf + k + n, ",\"cmd\":\"status\"}");
        hostile_str(buf, IMP_PROTO_E_BAD_JSON, NULL);
        free(buf);
}

static void nul_bytes(void) {
        for (size_t v = 0; v < ARRAY_SIZE(valid); v++) {
                size_t n = strlen(valid[v]);
                char *buf = malloc(n);
                for (size_t at = 0; at < n; at += 3) {
                        memcpy(buf, valid[v], n);
                        buf[at] = '\0';
                        hostile(buf, n, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_BAD_JSON, NULL);
                }
                free(buf);
        }
        hostile_str("{\"id\":1,\"cmd\":\"status\\u0000\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":\"a\\u0000b\",\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
}

static void bad_utf8(void) {
        static const char *const seqs[] = {
                "\xff", "\xfe", "\xc0\xaf", "\xe0\x80\xaf", "\xed\xa0\x80", "\xf4\x90\x80\x80",
                "\x80", "\xbf", "\xc3", "\xe2\x82", "\xf0\x9f\x98", "\xf8\x88\x80\x80\x80",
        };
        static const char *const where[] = {
                "{\"id\":\"%s\",\"cmd\":\"status\"}",
                "{\"id\":1,\"cmd\":\"sta%stus\"}",
                "{\"id\":1,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p%s\"}}",
                "{\"id\":1,\"cmd\":\"status\",\"args\":{\"k%s\":1}}",
                "{\"id\":1,\"cmd\":\"status\"%s}",
                "%s{\"id\":1,\"cmd\":\"status\"}",
        };
        char buf[256];
        for (size_t s = 0; s < ARRAY_SIZE(seqs); s++)
                for (size_t w = 0; w < ARRAY_SIZE(where); w++) {
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wformat-nonliteral"
                        snprintf(buf, sizeof buf, where[w], seqs[s]);
#pragma GCC diagnostic pop
                        hostile_str(buf, IMP_PROTO_E_BAD_JSON, NULL);
                }
        /* escaped lone surrogates */
        hostile_str("{\"id\":\"\\ud800\",\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("{\"id\":\"\\udc00x\",\"cmd\":\"status\"}", IMP_PROTO_E_BAD_JSON, NULL);
}

static void long_lines(void) {
        size_t sizes[] = { 70 * 1024, IMP_PROTO_REQUEST_MAX + 1, 200 * 1024, 1024 * 1024 };
        for (size_t s = 0; s < ARRAY_SIZE(sizes); s++) {
                size_t n = sizes[s];
                char *buf = malloc(n);
                /* a well-formed request that is merely too long */
                int k = sprintf(buf, "{\"id\":1,\"cmd\":\"plan.validate\",\"args\":{\"plan\":\"");
                memset(buf + k, 'p', n - (size_t) k);
                memcpy(buf + n - 3, "\"}}", 3);
                hostile(buf, n, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_TOO_LONG, NULL);
                /* random bytes with NULs */
                for (size_t i = 0; i < n; i++)
                        buf[i] = (char) rnd(256);
                hostile(buf, n, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_TOO_LONG, NULL);
                free(buf);
        }
        /* just under the limit: parsed, and refused for its content */
        size_t n = IMP_PROTO_REQUEST_MAX;
        char *buf = malloc(n);
        int k = sprintf(buf, "{\"id\":1,\"cmd\":\"status\",\"args\":{\"pad\":\"");
        memset(buf + k, 'q', n - (size_t) k);
        memcpy(buf + n - 3, "\"}}", 3);
        hostile(buf, n, IMP_PROTO_ROLE_OPERATOR, IMP_PROTO_E_BAD_ARGUMENT, "args.pad");
        free(buf);
}

/* Values that no field of the given type accepts (every string field has min length 1). */
static const char *const not_string[] = { "true", "0", "1.5", "[]", "{}", "[\"a\"]", "\"\"", "null" };
static const char *const not_token[] = { "\".hidden\"", "\"a b\"", "\"a/b\"", "\"\\u00e9\"" };
static const char *const not_integer[] = { "true", "\"5\"", "1.5", "[]", "{}", "0", "1001", "-1",
                                           "9223372036854775807", "[1]" };
static const char *const not_object[] = { "true", "0", "\"x\"", "[]", "[{}]", "2.5" };
static const char *const not_strings[] = { "\"progress\"", "{}", "[]", "[1]", "[\"nope\"]", "[\"\"]",
                                           "[null]", "[[\"frame\"]]",
                                           "[\"frame\",\"frame\",\"frame\",\"frame\",\"frame\",\"frame\","
                                           "\"frame\",\"frame\",\"frame\",\"frame\",\"frame\",\"frame\","
                                           "\"frame\",\"frame\",\"frame\",\"frame\",\"frame\"]" };

/* Minimal valid args for a command, as JSON members without braces, except `skip`. */
static void base_args(const struct imp_proto_command *c, const char *skip, char *out, size_t size) {
        size_t o = 0;
        out[0] = 0;
        for (const struct imp_proto_field *f = c->fields; f->name; f++) {
                if (!(f->flags & IMP_PROTO_F_REQUIRED) || !strcmp(f->name, skip))
                        continue;
                const char *v = f->choices ? "\"camera\"" : "\"ok-1\"";
                o += (size_t) snprintf(out + o, size - o, "%s\"%s\":%s", o ? "," : "", f->name, v);
        }
}

static void wrong_types(void) {
        size_t nc;
        const struct imp_proto_command *cmds = imp_proto_commands(&nc);
        char buf[1024], base[256], field[80];
        for (size_t i = 0; i < nc; i++) {
                const struct imp_proto_command *c = &cmds[i];
                /* the baseline is valid */
                base_args(c, "", base, sizeof base);
                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":\"%s\",\"args\":{%s}}", c->name, base);
                _cleanup_proto_request_ struct imp_proto_request req = {};
                CHECK_OK(imp_proto_parse_request(buf, strlen(buf), IMP_PROTO_ROLE_OPERATOR, &req, NULL));

                for (const struct imp_proto_field *f = c->fields; f->name; f++) {
                        const char *const *bad;
                        size_t nbad;
                        switch (f->type) {
                        case IMP_PROTO_T_STRING: bad = not_string; nbad = ARRAY_SIZE(not_string); break;
                        case IMP_PROTO_T_INTEGER: bad = not_integer; nbad = ARRAY_SIZE(not_integer); break;
                        case IMP_PROTO_T_OBJECT: bad = not_object; nbad = ARRAY_SIZE(not_object); break;
                        default: bad = not_strings; nbad = ARRAY_SIZE(not_strings); break;
                        }
                        base_args(c, f->name, base, sizeof base);
                        snprintf(field, sizeof field, "args.%s", f->name);
                        for (size_t b = 0; b < nbad + ((f->flags & IMP_PROTO_F_TOKEN) ? ARRAY_SIZE(not_token) : 0); b++) {
                                const char *v = b < nbad ? bad[b] : not_token[b - nbad];
                                bool optional_null = !strcmp(v, "null") && !(f->flags & IMP_PROTO_F_REQUIRED);
                                if (optional_null)
                                        continue;       /* null is absent, and absent is fine */
                                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":\"%s\",\"args\":{%s%s\"%s\":%s}}",
                                         c->name, base, base[0] ? "," : "", f->name, v);
                                const char *want_field = field;
                                if (f->type == IMP_PROTO_T_STRING_ARRAY && v[0] == '[' && v[1] && v[1] != ']' &&
                                    strlen(v) < 40)
                                        want_field = "args.events[0]";
                                hostile_str(buf, IMP_PROTO_E_BAD_ARGUMENT, want_field);
                        }
                }
                /* an argument the command does not have */
                base_args(c, "", base, sizeof base);
                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":\"%s\",\"args\":{%s%s\"zz\":1}}", c->name, base,
                         base[0] ? "," : "");
                hostile_str(buf, IMP_PROTO_E_BAD_ARGUMENT, "args.zz");
                /* observers and operator-only commands */
                if (c->operator_only) {
                        snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":\"%s\"}", c->name);
                        hostile(buf, strlen(buf), IMP_PROTO_ROLE_OBSERVER, IMP_PROTO_E_PERMISSION_DENIED, "cmd");
                }
        }
        /* the envelope: id, cmd, args */
        static const char *const ids[] = { "1.5", "true", "false", "null", "[]", "{}", "[1]", "\"\"" };
        for (size_t i = 0; i < ARRAY_SIZE(ids); i++) {
                snprintf(buf, sizeof buf, "{\"id\":%s,\"cmd\":\"status\"}", ids[i]);
                hostile_str(buf, IMP_PROTO_E_BAD_REQUEST, "id");
        }
        char longid[300];
        memset(longid, 'i', sizeof longid);
        snprintf(buf, sizeof buf, "{\"id\":\"%.*s\",\"cmd\":\"status\"}", IMP_PROTO_ID_MAX + 1, longid);
        hostile_str(buf, IMP_PROTO_E_BAD_REQUEST, "id");
        static const char *const cmds_bad[] = { "1", "true", "null", "[]", "{}", "[\"status\"]" };
        for (size_t i = 0; i < ARRAY_SIZE(cmds_bad); i++) {
                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":%s}", cmds_bad[i]);
                hostile_str(buf, IMP_PROTO_E_BAD_REQUEST, "cmd");
        }
        static const char *const names_bad[] = { "\"\"", "\"STATUS\"", "\"status \"", "\"session.\"",
                                                 "\"../status\"", "\"status.status\"" };
        for (size_t i = 0; i < ARRAY_SIZE(names_bad); i++) {
                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":%s}", names_bad[i]);
                hostile_str(buf, IMP_PROTO_E_UNKNOWN_COMMAND, "cmd");
        }
        static const char *const args_bad[] = { "1", "true", "\"x\"", "[]", "[{}]" };
        for (size_t i = 0; i < ARRAY_SIZE(args_bad); i++) {
                snprintf(buf, sizeof buf, "{\"id\":1,\"cmd\":\"status\",\"args\":%s}", args_bad[i]);
                hostile_str(buf, IMP_PROTO_E_BAD_REQUEST, "args");
        }
        static const char *const roots[] = { "1", "\"status\"", "[]", "null", "true", "[{\"id\":1,\"cmd\":\"status\"}]" };
        for (size_t i = 0; i < ARRAY_SIZE(roots); i++)
                hostile_str(roots[i], IMP_PROTO_E_BAD_REQUEST, NULL);
        hostile_str("{}", IMP_PROTO_E_BAD_REQUEST, "id");
        hostile_str("{\"id\":1,\"cmd\":\"status\",\"\\u0001x\\u00e9\":2}", IMP_PROTO_E_BAD_REQUEST, "?x??");   /* é is two bytes */
        hostile_str("{\"id\":1,\"cmd\":\"status\",\"cmd\":\"rig\"}", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("   ", IMP_PROTO_E_BAD_JSON, NULL);
        hostile_str("\t\r", IMP_PROTO_E_BAD_JSON, NULL);
}

int main(void) {
        CHECK_OK(imp_linebuf_new(IMP_PROTO_REQUEST_MAX, &server_lb));
        random_bytes();
        truncated();
        deep();
        numbers();
        nul_bytes();
        bad_utf8();
        long_lines();
        wrong_types();
        CHECK_INT_EQ(imp_linebuf_pending(server_lb), 0);
        imp_linebuf_free(server_lb);
        fprintf(stderr, "%d hostile messages, %d replies checked\n", cases, replies_checked);
        CHECK_INT_GE(cases, 1000);
        return TEST_DONE();
}
