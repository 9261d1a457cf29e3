/* Control protocol codec: every command round-trips with valid arguments; each error kind
 * yields exactly the documented code and field; roles; replies and events are one line;
 * the line splitter gives the same lines under any chunking. */
#include <errno.h>
#include <string.h>
#include "json-util.h"
#include "protocol.h"
#include "test.h"

/* One valid request per command (the table order). */
static const struct {
        const char *cmd, *line;
} valid[] = {
        { "status",         "{\"id\":1,\"cmd\":\"status\"}" },
        { "rig",            "{\"id\":2,\"cmd\":\"rig\",\"args\":{}}" },
        { "devices",        "{\"id\":\"d\",\"cmd\":\"devices\",\"args\":null}" },
        { "plan.validate",  "{\"id\":4,\"cmd\":\"plan.validate\",\"args\":{\"plan\":\"/etc/impasto/plans/a.json\"}}" },
        { "plan.estimate",  "{\"id\":5,\"cmd\":\"plan.estimate\",\"args\":{\"plan\":\"plans/b.json\"}}" },
        { "session.start",  "{\"id\":6,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p.json\",\"name\":\"night-watch_2\"}}" },
        { "session.pause",  "{\"id\":7,\"cmd\":\"session.pause\",\"args\":{\"session\":\"20250301-101500-nw\"}}" },
        { "session.resume", "{\"id\":8,\"cmd\":\"session.resume\",\"args\":{\"session\":\"s1\"}}" },
        { "session.abort",  "{\"id\":9,\"cmd\":\"session.abort\",\"args\":{\"session\":\"s1\"}}" },
        { "session.list",   "{\"id\":10,\"cmd\":\"session.list\",\"args\":{\"limit\":20}}" },
        { "session.show",   "{\"id\":11,\"cmd\":\"session.show\",\"args\":{\"session\":\"s1\"}}" },
        { "calibrate",      "{\"id\":12,\"cmd\":\"calibrate\",\"args\":{\"routine\":\"procam\",\"args\":{\"board\":\"charuco-7x5\"}}}" },
        { "jobs.list",      "{\"id\":13,\"cmd\":\"jobs.list\"}" },
        { "jobs.show",      "{\"id\":14,\"cmd\":\"jobs.show\",\"args\":{\"job\":\"j-42\"}}" },
        { "jobs.retry",     "{\"id\":15,\"cmd\":\"jobs.retry\",\"args\":{\"job\":\"j-42\"}}" },
        { "subscribe",      "{\"id\":16,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"progress\",\"done\"]}}" },
        { "unsubscribe",    "{\"id\":-17,\"cmd\":\"unsubscribe\"}" },
        { "calibration.list", "{\"id\":18,\"cmd\":\"calibration.list\",\"args\":{\"limit\":5}}" },
        { "calibration.show", "{\"id\":19,\"cmd\":\"calibration.show\",\"args\":{\"calibration\":\"3\"}}" },
        { "queue.add",      "{\"id\":20,\"cmd\":\"queue.add\",\"args\":{\"plan\":\"p.cfg\",\"name\":\"nw\"}}" },
        { "queue.list",     "{\"id\":21,\"cmd\":\"queue.list\"}" },
        { "queue.move",     "{\"id\":22,\"cmd\":\"queue.move\",\"args\":{\"id\":\"q3\",\"position\":1}}" },
        { "queue.cancel",   "{\"id\":23,\"cmd\":\"queue.cancel\",\"args\":{\"id\":\"q3\"}}" },
        { "report",         "{\"id\":24,\"cmd\":\"report\",\"args\":{\"since\":\"2026-11-26T00:00:00Z\"}}" },
};

static void test_table(void) {
        size_t n = 0;
        const struct imp_proto_command *c = imp_proto_commands(&n);
        CHECK_INT_EQ(n, ARRAY_SIZE(valid));
        CHECK_INT_EQ(n, _IMP_PROTO_CMD_MAX);
        for (size_t i = 0; i < n; i++) {
                CHECK_STR_EQ(c[i].name, valid[i].cmd);
                CHECK_INT_EQ(c[i].cmd, i);
                CHECK(imp_proto_command_find(c[i].name) == &c[i]);
        }
        CHECK(!imp_proto_command_find("session"));
        CHECK(!imp_proto_command_find(NULL));
        CHECK(imp_proto_command_find("session.start")->operator_only);
        CHECK(!imp_proto_command_find("session.list")->operator_only);
}

/* Reply, serialise, parse as a client: the id and the result come back. */
static void test_round_trips(void) {
        for (size_t i = 0; i < ARRAY_SIZE(valid); i++) {
                _cleanup_proto_request_ struct imp_proto_request req = {};
                _cleanup_proto_error_ struct imp_proto_error e = {};
                int r = imp_proto_parse_request(valid[i].line, strlen(valid[i].line), IMP_PROTO_ROLE_OPERATOR,
                                                &req, &e);
                CHECK_MSG(r == 0, "%s: %d %s %s: %s", valid[i].line, r, imp_proto_error_code_name(e.code),
                          e.field, e.message);
                if (r < 0)
                        continue;
                CHECK_STR_EQ(req.command->name, valid[i].cmd);
                CHECK(json_is_object(req.args));
                CHECK(json_is_integer(req.id) || json_is_string(req.id));
                CHECK(!e.id);

                _cleanup_json_ json_t *reply = imp_proto_reply_ok(req.id, json_pack("{s:s}", "echo", valid[i].cmd));
                _cleanup_free_ char *line = imp_proto_dump_line(reply);
                CHECK(line && line[strlen(line) - 1] == '\n' && strchr(line, '\n') == line + strlen(line) - 1);
                _cleanup_proto_message_ struct imp_proto_message m = {};
                CHECK_OK(imp_proto_parse_reply(line, strlen(line) - 1, &m, &e));
                CHECK_INT_EQ(m.kind, IMP_PROTO_MSG_REPLY);
                CHECK(m.ok);
                CHECK(json_equal((json_t *) m.id, req.id));
                CHECK_STR_EQ(json_string_value(json_object_get(m.result, "echo")), valid[i].cmd);
        }
        /* args that were given are handed over as they are */
        _cleanup_proto_request_ struct imp_proto_request req = {};
        const char *l = valid[11].line;
        CHECK_OK(imp_proto_parse_request(l, strlen(l), IMP_PROTO_ROLE_OPERATOR, &req, NULL));
        CHECK_INT_EQ(req.command->cmd, IMP_PROTO_CMD_CALIBRATE);
        CHECK_STR_EQ(json_string_value(json_object_get(req.args, "routine")), "procam");
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(req.args, "args"), "board")), "charuco-7x5");
}

/* Each malformed request: its code, field, errno return and a phrase of the message. */
static const struct {
        const char *line;
        enum imp_proto_role role;
        int ret;
        enum imp_proto_errcode code;
        const char *field;              /* "" when none */
        const char *says;
        const char *id;                 /* the id the error reply carries, as JSON */
} bad[] = {
        { "{\"id\":1,\"cmd\":\"status\"", 1, -EBADMSG, IMP_PROTO_E_BAD_JSON, "", "column", "null" },
        { "not json", 1, -EBADMSG, IMP_PROTO_E_BAD_JSON, "", "invalid JSON at column 3", "null" },
        { "{\"id\":1,\"id\":2,\"cmd\":\"status\"}", 1, -EBADMSG, IMP_PROTO_E_BAD_JSON, "", "duplicate", "null" },
        { "[1,2]", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "", "expected a JSON object, got an array", "null" },
        { "42", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "", "got an integer", "null" },
        { "{\"cmd\":\"status\"}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "id", "missing", "null" },
        { "{\"id\":1.5,\"cmd\":\"status\"}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "id", "got a number", "null" },
        { "{\"id\":[1],\"cmd\":\"status\"}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "id", "got an array", "null" },
        { "{\"id\":\"\",\"cmd\":\"status\"}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "id", "1 to 128", "null" },
        { "{\"id\":7}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "cmd", "missing", "7" },
        { "{\"id\":7,\"cmd\":3}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "cmd", "got an integer", "7" },
        { "{\"id\":\"x\",\"cmd\":\"status\",\"args\":[]}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "args",
          "expected an object", "\"x\"" },
        { "{\"id\":7,\"cmd\":\"status\",\"arg\":{}}", 1, -EINVAL, IMP_PROTO_E_BAD_REQUEST, "arg", "unknown member", "7" },
        { "{\"id\":7,\"cmd\":\"session.explode\"}", 1, -EOPNOTSUPP, IMP_PROTO_E_UNKNOWN_COMMAND, "cmd", "unknown command", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT, "args.plan",
          "missing; expected a string", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":5}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.plan", "expected a string", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":\"\"}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.plan", "of 1 to", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p\",\"name\":\"../etc\"}}", 1, -EINVAL,
          IMP_PROTO_E_BAD_ARGUMENT, "args.name", "not starting with '.'", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p\",\"name\":\"a/b\"}}", 1, -EINVAL,
          IMP_PROTO_E_BAD_ARGUMENT, "args.name", "letters, digits", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p\",\"speed\":2}}", 1, -EINVAL,
          IMP_PROTO_E_BAD_ARGUMENT, "args.speed", "unknown argument", "7" },
        { "{\"id\":7,\"cmd\":\"session.pause\",\"args\":{\"session\":true}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.session", "expected a string (session id), got a boolean", "7" },
        { "{\"id\":7,\"cmd\":\"session.list\",\"args\":{\"limit\":0}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.limit", "expected an integer from 1 to 1000", "7" },
        { "{\"id\":7,\"cmd\":\"session.list\",\"args\":{\"limit\":\"5\"}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.limit", "got a string", "7" },
        { "{\"id\":7,\"cmd\":\"calibrate\",\"args\":{\"routine\":\"lens\"}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.routine", "expected one of camera, procam, lights, radiometric, projector-gamma", "7" },
        { "{\"id\":7,\"cmd\":\"calibrate\",\"args\":{\"routine\":\"camera\",\"args\":[1]}}", 1, -EINVAL,
          IMP_PROTO_E_BAD_ARGUMENT, "args.args", "expected an object", "7" },
        { "{\"id\":7,\"cmd\":\"subscribe\",\"args\":{\"events\":\"progress\"}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT,
          "args.events", "expected an array of 1 to 16 strings", "7" },
        { "{\"id\":7,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"frame\",\"weather\"]}}", 1, -EINVAL,
          IMP_PROTO_E_BAD_ARGUMENT, "args.events[1]", "expected one of progress, frame", "7" },
        { "{\"id\":7,\"cmd\":\"jobs.retry\",\"args\":{}}", 1, -EINVAL, IMP_PROTO_E_BAD_ARGUMENT, "args.job",
          "missing", "7" },
        { "{\"id\":7,\"cmd\":\"session.start\",\"args\":{\"plan\":\"p\"}}", 0, -EPERM,
          IMP_PROTO_E_PERMISSION_DENIED, "cmd", "operator role", "7" },
        /* the role is checked before the arguments: observers learn nothing about them */
        { "{\"id\":7,\"cmd\":\"session.abort\",\"args\":{}}", 0, -EPERM, IMP_PROTO_E_PERMISSION_DENIED, "cmd",
          "impasto-operators", "7" },
        { "{\"id\":\"a\",\"cmd\":\"status\",\"args\":{\"x\":[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]}}",
          1, -EBADMSG, IMP_PROTO_E_BAD_JSON, "", "nested deeper than 32", "null" },
        { "{\"id\":1,\"cmd\":\"status\",\"args\":{\"n\":123456789012345678901234567890}}", 1, -EBADMSG,
          IMP_PROTO_E_BAD_JSON, "", "too big", "null" },
};

static void test_errors(void) {
        for (size_t i = 0; i < ARRAY_SIZE(bad); i++) {
                const char *l = bad[i].line;
                size_t len = strlen(l);
                struct imp_proto_request req = { .id = (json_t *) 0x1 };       /* must stay untouched */
                _cleanup_proto_error_ struct imp_proto_error e = {};
                int r = imp_proto_parse_request(l, len, bad[i].role, &req, &e);
                CHECK_MSG(r == bad[i].ret, "%s: returned %d, expected %d", l, r, bad[i].ret);
                CHECK_MSG(e.code == bad[i].code, "%s: code %s, expected %s", l, imp_proto_error_code_name(e.code),
                          imp_proto_error_code_name(bad[i].code));
                CHECK_STR_EQ(e.field, bad[i].field);
                CHECK_STR_CONTAINS(e.message, bad[i].says);
                CHECK(req.id == (json_t *) 0x1 && !req.args);
                CHECK_INT_EQ(e.sys_errno, -bad[i].ret);

                /* the error reply: one line carrying the id, the code, the field */
                _cleanup_json_ json_t *reply = imp_proto_reply_error(NULL, &e);
                _cleanup_free_ char *line = imp_proto_dump_line(reply);
                CHECK(line && strchr(line, '\n') == line + strlen(line) - 1);
                _cleanup_json_ json_t *id = json_loads(bad[i].id, JSON_DECODE_ANY, NULL);
                CHECK_MSG(json_equal(json_object_get(reply, "id"), id), "%s: id in %s", l, line);
                json_t *err = json_object_get(reply, "error");
                CHECK_STR_EQ(json_string_value(json_object_get(err, "code")), imp_proto_error_code_name(bad[i].code));
                CHECK_INT_EQ(json_integer_value(json_object_get(err, "errno")), -bad[i].ret);
                if (bad[i].field[0])
                        CHECK_STR_EQ(json_string_value(json_object_get(err, "field")), bad[i].field);
                else
                        CHECK(!json_object_get(err, "field"));
                CHECK(json_is_false(json_object_get(reply, "ok")));
        }
}

static void test_too_long_and_limits(void) {
        size_t n = IMP_PROTO_REQUEST_MAX + 1;
        char *big = malloc(n + 1);
        const char *head = "{\"id\":1,\"cmd\":\"plan.validate\",\"args\":{\"plan\":\"";
        memset(big, 'a', n);
        memcpy(big, head, strlen(head));
        memcpy(big + n - 3, "\"}}", 3);
        big[n] = 0;
        _cleanup_proto_error_ struct imp_proto_error e = {};
        struct imp_proto_request req = {};
        CHECK_ERR(imp_proto_parse_request(big, n, IMP_PROTO_ROLE_OPERATOR, &req, &e), -E2BIG);
        CHECK_INT_EQ(e.code, IMP_PROTO_E_TOO_LONG);
        CHECK_INT_EQ(e.sys_errno, E2BIG);
        /* one byte less is a request; its plan is too long for a path */
        memcpy(big + n - 4, "\"}}", 3);
        CHECK_ERR(imp_proto_parse_request(big, n - 1, IMP_PROTO_ROLE_OPERATOR, &req, &e), -EINVAL);
        CHECK_INT_EQ(e.code, IMP_PROTO_E_BAD_ARGUMENT);
        CHECK_STR_EQ(e.field, "args.plan");
        free(big);

        /* 32 levels pass the depth check, 33 do not */
        char deep[200];
        int k = snprintf(deep, sizeof deep, "{\"id\":1,\"cmd\":\"status\",\"x\":");
        for (int i = 0; i < 31; i++)
                deep[k++] = '[';
        for (int i = 0; i < 31; i++)
                deep[k++] = ']';
        deep[k++] = '}';
        deep[k] = 0;
        CHECK_ERR(imp_proto_parse_request(deep, strlen(deep), IMP_PROTO_ROLE_OPERATOR, &req, &e), -EINVAL);
        CHECK_INT_EQ(e.code, IMP_PROTO_E_BAD_REQUEST);  /* got past the parser: "x" is unknown */
        CHECK_STR_EQ(e.field, "x");
        /* brackets inside strings do not count */
        char str[300];
        k = snprintf(str, sizeof str, "{\"id\":\"[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[\\\"[[[[[\",\"cmd\":\"status\"}");
        _cleanup_proto_request_ struct imp_proto_request ok = {};
        CHECK_OK(imp_proto_parse_request(str, (size_t) k, IMP_PROTO_ROLE_OBSERVER, &ok, &e));
}

static void test_nul(void) {
        static const char l[] = "{\"id\":1,\"cmd\":\"st\0tus\"}";
        struct imp_proto_request req = {};
        _cleanup_proto_error_ struct imp_proto_error e = {};
        CHECK_ERR(imp_proto_parse_request(l, sizeof l - 1, IMP_PROTO_ROLE_OPERATOR, &req, &e), -EBADMSG);
        CHECK_INT_EQ(e.code, IMP_PROTO_E_BAD_JSON);
        CHECK_STR_CONTAINS(e.message, "column 18: NUL byte");
        /* an escaped NUL is valid JSON but no command name */
        static const char l2[] = "{\"id\":1,\"cmd\":\"status\\u0000x\"}";
        CHECK_ERR(imp_proto_parse_request(l2, sizeof l2 - 1, IMP_PROTO_ROLE_OPERATOR, &req, &e), -EBADMSG);
        CHECK_INT_EQ(e.code, IMP_PROTO_E_BAD_JSON);     /* jansson refuses \u0000 without JSON_ALLOW_NUL */
}

static void test_roles(void) {
        size_t n;
        const struct imp_proto_command *c = imp_proto_commands(&n);
        int denied = 0;
        for (size_t i = 0; i < n; i++) {
                _cleanup_proto_request_ struct imp_proto_request req = {};
                _cleanup_proto_error_ struct imp_proto_error e = {};
                int r = imp_proto_parse_request(valid[i].line, strlen(valid[i].line), IMP_PROTO_ROLE_OBSERVER, &req, &e);
                if (c[i].operator_only) {
                        CHECK_ERR(r, -EPERM);
                        CHECK_INT_EQ(e.code, IMP_PROTO_E_PERMISSION_DENIED);
                        CHECK_INT_EQ(imp_proto_exit_status(e.code), IMP_EXIT_PERMISSION);
                        denied++;
                } else
                        CHECK_OK(r);
        }
        CHECK_INT_EQ(denied, 9);        /* session.start/pause/resume/abort, calibrate, jobs.retry, queue.add/move/cancel */

        _cleanup_json_ json_t *b = imp_proto_banner(IMP_PROTO_ROLE_OBSERVER);
        _cleanup_free_ char *line = imp_proto_dump_line(b);
        CHECK_STR_EQ(line, "{\"impasto\":\"0.1.0\",\"protocol\":1,\"role\":\"observer\"}\n");
        _cleanup_proto_message_ struct imp_proto_message m = {};
        CHECK_OK(imp_proto_parse_reply(line, strlen(line) - 1, &m, NULL));
        CHECK_INT_EQ(m.kind, IMP_PROTO_MSG_BANNER);
        CHECK_INT_EQ(m.protocol, IMP_PROTO_VERSION);
        CHECK_INT_EQ(m.role, IMP_PROTO_ROLE_OBSERVER);
        CHECK_STR_EQ(m.version, "0.1.0");
}

static bool one_line(const char *s) {
        return s && strlen(s) > 0 && strchr(s, '\n') == s + strlen(s) - 1;
}

static void test_one_line(void) {
        _cleanup_json_ json_t *id = json_string("multi\nline\r\nid");
        _cleanup_json_ json_t *ok = imp_proto_reply_ok(id, json_pack("{s:s, s:[s]}", "note", "a\nb\n\n",
                                                                     "log", "line 1\nline 2\n"));
        _cleanup_free_ char *l1 = imp_proto_dump_line(ok);
        CHECK(one_line(l1));
        CHECK_STR_CONTAINS(l1, "\"note\":\"a\\nb\\n\\n\"");

        struct imp_proto_error e = {};
        imp_proto_error_set(&e, IMP_PROTO_E_DEVICE, ETIMEDOUT, "dome", "light 3 did not answer\nafter %d ms", 500);
        _cleanup_json_ json_t *er = imp_proto_reply_error(id, &e);
        _cleanup_free_ char *l2 = imp_proto_dump_line(er);
        CHECK(one_line(l2));
        _cleanup_proto_message_ struct imp_proto_message m = {};
        CHECK_OK(imp_proto_parse_reply(l2, strlen(l2) - 1, &m, NULL));
        CHECK(!m.ok);
        CHECK_INT_EQ(m.error.code, IMP_PROTO_E_DEVICE);
        CHECK_INT_EQ(m.error.sys_errno, ETIMEDOUT);
        CHECK_STR_EQ(m.error.field, "dome");
        CHECK_STR_EQ(m.error.message, "light 3 did not answer\nafter 500 ms");
        CHECK(json_equal((json_t *) m.id, id));
        CHECK_INT_EQ(imp_proto_exit_status(m.error.code), IMP_EXIT_FAILURE);

        /* a message cut inside a UTF-8 character still makes a valid line */
        memset(e.message, 0, sizeof e.message);
        memcpy(e.message, "caf\xc3", 4);
        _cleanup_json_ json_t *cut = imp_proto_reply_error(NULL, &e);
        CHECK(cut);
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(cut, "error"), "message")), "caf?");
        CHECK(json_is_null(json_object_get(cut, "id")));

        _cleanup_json_ json_t *ev = imp_proto_event("frame", 41, json_pack("{s:s, s:s, s:i, s:s}", "session", "s\n1",
                                                                              "camera", "cam0", "step", 3,
                                                                              "file", "frames/0003\n.tif"));
        _cleanup_free_ char *l3 = imp_proto_dump_line(ev);
        CHECK(one_line(l3));
        CHECK(!strncmp(l3, "{\"event\":\"frame\",\"seq\":41,", 26));
        _cleanup_proto_message_ struct imp_proto_message me = {};
        CHECK_OK(imp_proto_parse_reply(l3, strlen(l3) - 1, &me, NULL));
        CHECK_INT_EQ(me.kind, IMP_PROTO_MSG_EVENT);
        CHECK_STR_EQ(me.event, "frame");
        CHECK_INT_EQ(me.seq, 41);
        CHECK_STR_EQ(json_string_value(me.session), "s\n1");

        /* fields cannot override event and seq; unknown types are refused */
        _cleanup_json_ json_t *ev2 = imp_proto_event("done", 2, json_pack("{s:s, s:i}", "event", "x", "seq", 99));
        CHECK_STR_EQ(json_string_value(json_object_get(ev2, "event")), "done");
        CHECK_INT_EQ(json_integer_value(json_object_get(ev2, "seq")), 2);
        CHECK(!imp_proto_event("weather", 1, json_object()));
        CHECK(!imp_proto_event("done", 1, json_array()));
        _cleanup_json_ json_t *ev3 = imp_proto_event("job", 3, NULL);
        CHECK(ev3 && json_object_size(ev3) == 2);
}

static void test_client_parser(void) {
        static const struct { const char *line; const char *field; } bad_lines[] = {
                { "{\"id\":1,\"ok\":\"yes\",\"result\":{}}", "ok" },
                { "{\"ok\":true,\"result\":{}}", "id" },
                { "{\"id\":1,\"ok\":true}", "result" },
                { "{\"id\":1,\"ok\":false,\"error\":{\"code\":\"busy\",\"message\":\"m\"}}", "error.errno" },
                { "{\"id\":1,\"ok\":false,\"error\":{\"code\":1,\"errno\":0,\"message\":\"m\"}}", "error.code" },
                { "{\"event\":\"frame\",\"seq\":-1}", "seq" },
                { "{\"impasto\":\"0.1.0\",\"protocol\":1,\"role\":\"admin\"}", "role" },
                { "{\"hello\":1}", "" },
                { "[]", "" },
        };
        for (size_t i = 0; i < ARRAY_SIZE(bad_lines); i++) {
                struct imp_proto_message m = {};
                _cleanup_proto_error_ struct imp_proto_error e = {};
                CHECK_ERR(imp_proto_parse_reply(bad_lines[i].line, strlen(bad_lines[i].line), &m, &e), -EBADMSG);
                CHECK_STR_EQ(e.field, bad_lines[i].field);
                CHECK(!m.root);
        }
        _cleanup_proto_message_ struct imp_proto_message m = {};
        const char *l = "{\"id\":3,\"ok\":false,\"error\":{\"code\":\"quota_exceeded\",\"errno\":122,\"message\":\"m\"},\"extra\":1}";
        CHECK_OK(imp_proto_parse_reply(l, strlen(l), &m, NULL));
        CHECK_INT_EQ(m.error.code, IMP_PROTO_E_UNKNOWN);        /* newer daemon: still a failure */
        CHECK_INT_EQ(imp_proto_exit_status(m.error.code), IMP_EXIT_FAILURE);

        for (int c = IMP_PROTO_E_TOO_LONG; c < IMP_PROTO_E_UNKNOWN; c++)
                CHECK_INT_EQ(imp_proto_error_code_from_name(imp_proto_error_code_name(c)), c);
        CHECK_INT_EQ(imp_proto_exit_status(IMP_PROTO_E_BAD_ARGUMENT), IMP_EXIT_BAD_INPUT);
        CHECK_INT_EQ(imp_proto_exit_status(IMP_PROTO_E_INVALID_PLAN), IMP_EXIT_BAD_INPUT);
        CHECK_INT_EQ(imp_proto_exit_status(IMP_PROTO_E_NONE), IMP_EXIT_OK);
}

/* ---- Line splitter ---- */

/* Feed `data` in chunks given by next_chunk and collect every result of next(). */
static char *split(const char *data, size_t n, size_t max, size_t (*next_chunk)(size_t left)) {
        _cleanup_linebuf_ struct imp_linebuf *lb = NULL;
        if (imp_linebuf_new(max, &lb) < 0)
                return NULL;
        size_t cap = 2 * n + 64, o = 0;
        char *out = calloc(1, cap);
        for (size_t at = 0; at < n;) {
                size_t k = next_chunk(n - at);     /* not inside IMP_MIN: it would run twice */
                k = IMP_MIN(k, n - at);
                if (imp_linebuf_feed(lb, data + at, k) < 0)
                        break;
                at += k;
                char *line;
                size_t len;
                int r;
                while ((r = imp_linebuf_next(lb, &line, &len)) != 0) {
                        if (r == -E2BIG)
                                o += (size_t) snprintf(out + o, cap - o, "<E2BIG>|");
                        else {
                                CHECK_INT_EQ(strlen(line), len);
                                CHECK(len <= max);
                                o += (size_t) snprintf(out + o, cap - o, "%s|", line);
                        }
                }
        }
        o += (size_t) snprintf(out + o, cap - o, "pending=%zu", imp_linebuf_pending(lb));
        return out;
}

static size_t one_byte(size_t left) { return 1; }
static size_t everything(size_t left) { return left; }
static unsigned rng_state = 12345;
static size_t random_chunk(size_t left) {
        rng_state = rng_state * 1103515245u + 12345u;
        return 1 + (rng_state >> 16) % 23;
}

static void test_linebuf(void) {
        static const char stream[] =
                "{\"id\":1}\n"
                "\n"                            /* blank: skipped */
                "second line\r\n"
                "\r\n"
                "0123456789abcdefghij-way-too-long-for-max-16\n"
                "ok\n"
                "xxxxxxxxxxxxxxxxx"             /* 17 bytes then more, newline far away */
                "yyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyy\n"
                "0123456789abcdef\n"            /* exactly max */
                "after\n"
                "tail-no-newline";
        const char *expect = "{\"id\":1}|second line\r|<E2BIG>|ok|<E2BIG>|0123456789abcdef|after|pending=15";
        size_t n = sizeof stream - 1;
        _cleanup_free_ char *a = split(stream, n, 16, everything);
        _cleanup_free_ char *b = split(stream, n, 16, one_byte);
        CHECK_STR_EQ(a, expect);
        CHECK_STR_EQ(b, expect);
        for (int seed = 0; seed < 50; seed++) {
                rng_state = (unsigned) seed * 7919u + 1;
                _cleanup_free_ char *c = split(stream, n, 16, random_chunk);
                CHECK_STR_EQ(c, expect);
        }

        _cleanup_linebuf_ struct imp_linebuf *lb = NULL;
        CHECK_ERR(imp_linebuf_new(0, &lb), -EINVAL);
        CHECK_OK(imp_linebuf_new(IMP_PROTO_REQUEST_MAX, &lb));
        char *line;
        size_t len;
        CHECK_ERR(imp_linebuf_next(lb, &line, &len), 0);
        CHECK_OK(imp_linebuf_feed(lb, NULL, 0));
        /* a 70 KiB line arriving in 4 KiB reads: one E2BIG, memory stays bounded, then a line */
        char chunk[4096];
        memset(chunk, 'z', sizeof chunk);
        int e2big = 0;
        for (int i = 0; i < 70 * 1024 / 4096; i++) {
                CHECK_OK(imp_linebuf_feed(lb, chunk, sizeof chunk));
                int r;
                while ((r = imp_linebuf_next(lb, &line, &len)) != 0)
                        e2big += r == -E2BIG;
                CHECK(imp_linebuf_pending(lb) <= IMP_PROTO_REQUEST_MAX + sizeof chunk);
        }
        CHECK_OK(imp_linebuf_feed(lb, "zzz\n{\"id\":2}\n", 13));
        CHECK_INT_EQ(imp_linebuf_next(lb, &line, &len), 1);
        CHECK_STR_EQ(line, "{\"id\":2}");
        CHECK_INT_EQ(imp_linebuf_next(lb, &line, &len), 0);
        CHECK_INT_EQ(e2big, 1);
        CHECK_INT_EQ(imp_linebuf_pending(lb), 0);
}

int main(void) {
        test_table();
        test_round_trips();
        test_errors();
        test_too_long_and_limits();
        test_nul();
        test_roles();
        test_one_line();
        test_client_parser();
        test_linebuf();
        return TEST_DONE();
}
