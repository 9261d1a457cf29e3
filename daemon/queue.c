/* The scan queue (docs/daemon.md, "The night"): plans queued by operators, started one after
 * another, each as its own session, when the rig is free — no session holds it and none is
 * paused or interrupted (that one is the operator's to resume or abort first: `status` says
 * so). STATE/queue.json is the truth, rewritten crash-safely (temporary file, fsync, rename,
 * directory fsync) at every change, so the queue survives a restart. An entry leaves the
 * queue when its session has started (the session is durable from then on); a plan that
 * cannot start stays as `failed` with the reason, and the queue goes on with the next one.
 * The plan path is confined when added, and again with the adding client's credentials when
 * the entry starts (the file may have changed meanwhile). */
#include <string.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "night.h"

struct queue_entry {
        struct queue_entry *next;
        char id[16];
        char plan[PATH_MAX];
        char name[65];
        char added[32];
        char error[512];                /* non-empty: it could not start (state failed) */
        struct daemon_peer peer;        /* who added it: the plan is read with their rights */
};

static void queue_path(struct daemon *d, char *buf, size_t size) {
        snprintf(buf, size, "%s/queue.json", d->state_dir);
}

static json_t *entry_json(const struct queue_entry *q, unsigned pos) {
        return json_pack("{s:s, s:i, s:s, s:s, s:s, s:s, s:s?, s:i}", "id", q->id, "position", (int) pos, "plan",
                         q->plan, "name", q->name, "added", q->added, "state", q->error[0] ? "failed" : "queued",
                         "error", q->error[0] ? q->error : NULL, "uid", (int) q->peer.uid);
}

static int queue_save(struct daemon *d) {
        struct night *n = d->night;
        json_t *a = json_array();
        unsigned pos = 1;
        for (struct queue_entry *q = n->queue; q; q = q->next) {
                json_t *e = entry_json(q, pos++), *groups = json_array();
                for (int i = 0; i < q->peer.n_groups; i++)
                        json_array_append_new(groups, json_integer(q->peer.groups[i]));
                json_object_set_new(e, "gid", json_integer(q->peer.gid));
                json_object_set_new(e, "groups", q->peer.n_groups >= 0 ? groups : json_null());
                if (q->peer.n_groups < 0)
                        json_decref(groups);
                json_array_append_new(a, e);
        }
        _cleanup_json_ json_t *j = json_pack("{s:i, s:o}", "next_id", (int) n->queue_next_id, "entries", a);
        char p[PATH_MAX + 16];
        queue_path(d, p, sizeof p);
        struct imp_error e = { 0 };
        int r = j ? imp_json_save_atomic(p, j, &e) : -ENOMEM;
        if (r < 0)
                log_error_errno(r, "scan queue: saving %s: %s", p, e.msg[0] ? e.msg : "out of memory");
        return r;
}

static int entry_from_json(const json_t *e, const char *what, struct queue_entry *q, struct imp_error *err) {
        const char *id = NULL, *plan = NULL, *name = NULL, *added = NULL, *error = NULL;
        long long uid = 0, gid = 0;
        int r;
        if ((r = imp_json_get_string(e, "id", true, &id, what, err)) < 0 ||
            (r = imp_json_get_string(e, "plan", true, &plan, what, err)) < 0 ||
            (r = imp_json_get_string(e, "name", true, &name, what, err)) < 0 ||
            (r = imp_json_get_string(e, "added", false, &added, what, err)) < 0 ||
            (r = imp_json_get_string(e, "error", false, &error, what, err)) < 0 ||
            (r = imp_json_get_int(e, "uid", true, &uid, what, err)) < 0 ||
            (r = imp_json_get_int(e, "gid", true, &gid, what, err)) < 0)
                return r;
        if (uid < 0 || uid >= UINT32_MAX || gid < 0 || gid >= UINT32_MAX || strlen(id) >= sizeof q->id)
                return imp_error_set(err, -EINVAL, "%s: expected id of at most 15 bytes, uid and gid from 0 to %u",
                                     what, UINT32_MAX - 1);
        /* cut to fit, a string could end inside a character: the entry would vanish from the
         * listing and from the next queue.json saved */
        const struct {
                const char *key, *v;
                size_t max;
        } str[] = { { "plan", plan, sizeof q->plan - 1 }, { "name", name, sizeof q->name - 1 },
                    { "added", added ? added : "", sizeof q->added - 1 }, { "error", error ? error : "", sizeof q->error - 1 } };
        for (size_t i = 0; i < ARRAY_SIZE(str); i++)
                if (strlen(str[i].v) > str[i].max)
                        return imp_error_set(err, -EINVAL, "%s%s: expected at most %zu bytes, got %zu", what, str[i].key,
                                             str[i].max, strlen(str[i].v));
        snprintf(q->id, sizeof q->id, "%s", id);
        snprintf(q->plan, sizeof q->plan, "%s", plan);
        snprintf(q->name, sizeof q->name, "%s", name);
        snprintf(q->added, sizeof q->added, "%s", added ? added : "");
        snprintf(q->error, sizeof q->error, "%s", error ? error : "");
        q->peer.uid = (uid_t) uid;
        q->peer.gid = (gid_t) gid;
        const json_t *groups = json_object_get(e, "groups"), *g;
        size_t i;
        q->peer.n_groups = json_is_array(groups) ? 0 : -1;
        json_array_foreach(groups, i, g)
                if (json_is_integer(g) && q->peer.n_groups < DAEMON_PEER_GROUPS_MAX)
                        q->peer.groups[q->peer.n_groups++] = (gid_t) json_integer_value(g);
        return 0;
}

/* A damaged queue.json (not JSON, truncated, a field of the wrong type) is never rewritten
 * over: it is moved aside to queue.json.damaged-TIME, the entries that could be read stay
 * queued (saved anew), the journal and `status` name the file, the field and where the
 * rest is. When it cannot be moved the queue stops (queue_broken) until it is fixed. */
static void queue_set_aside(struct daemon *d, const char *p, const char *msg, unsigned n_lost) {
        /* n_lost 0: the file could not be read at all */
        struct night *n = d->night;
        char ts[32], aside[PATH_MAX + 64];
        rfc3339_now(ts);
        snprintf(aside, sizeof aside, "%s.damaged-%s", p, ts);
        if (rename(p, aside) < 0) {
                n->queue_broken = true;
                log_error("scan queue %s; moving it to %s: %m; the queue is stopped until the file is fixed or removed",
                          msg, aside);
                return;
        }
        char lost[64] = "none of its entries could be read";
        if (n_lost)
                snprintf(lost, sizeof lost, "%u entr%s not queued", n_lost, n_lost == 1 ? "y" : "ies");
        snprintf(n->queue_damaged, sizeof n->queue_damaged, "%.700s; kept as %.200s (%s)", msg, aside, lost);
        log_error("scan queue %s; the queue goes on with the %u entries that could be read", n->queue_damaged,
                  n->n_queue);
        (void) queue_save(d);
}

static struct queue_entry *entry_find(struct daemon *d, const char *id, struct queue_entry ***ret_link);

int queue_load(struct daemon *d) {
        struct night *n = d->night;
        char p[PATH_MAX + 16];
        queue_path(d, p, sizeof p);
        n->queue_next_id = 1;
        if (access(p, F_OK) < 0)
                return 0;
        _cleanup_json_ json_t *j = NULL;
        struct imp_error err = { 0 }, first = { 0 };
        int r = imp_json_load(p, &j, &err);
        const json_t *a = json_object_get(j, "entries"), *e;
        if (r >= 0 && !json_is_array(a))
                r = imp_error_set(&err, -EINVAL, "%s: entries: expected an array", p);
        if (r < 0)
                first = err;
        size_t i;
        unsigned lost = 0;
        struct queue_entry **tail = &n->queue;
        json_array_foreach(a, i, e) {
                if (r < 0)
                        break;
                struct queue_entry *q = n->n_queue < NIGHT_QUEUE_MAX ? calloc(1, sizeof *q) : NULL;
                char what[PATH_MAX + 64];
                snprintf(what, sizeof what, "%s: entries[%zu].", p, i);
                int k = q ? entry_from_json(e, what, q, &err) :
                        imp_error_set(&err, -ENOSPC, "%sa queue holds at most %d entries", what, NIGHT_QUEUE_MAX);
                if (k == 0 && entry_find(d, q->id, NULL))       /* `queue cancel ID` would pick one */
                        k = imp_error_set(&err, -EINVAL, "%sid: \"%s\" is the id of an earlier entry", what, q->id);
                if (k < 0) {            /* this entry is lost to the queue (kept in the file set aside) */
                        free(q);
                        if (!lost++)
                                first = err;
                        continue;
                }
                *tail = q;
                tail = &q->next;
                n->n_queue++;
        }
        json_t *next = json_object_get(j, "next_id");
        if (json_is_integer(next) && json_integer_value(next) > 0 && json_integer_value(next) < 1000000000)
                n->queue_next_id = (unsigned) json_integer_value(next);
        else if (r < 0 || lost)
                n->queue_next_id = 1000;        /* ids of the lost entries are not reused */
        /* a next_id at or below an id in use (a hand-edited file) would give a new entry that id */
        for (struct queue_entry *q = n->queue; q; q = q->next) {
                unsigned k;
                char end;
                if (sscanf(q->id, "q%u%c", &k, &end) == 1 && k >= n->queue_next_id && k < 1000000000)
                        n->queue_next_id = k + 1;
        }
        if (r < 0 || lost) {
                queue_set_aside(d, p, first.msg, r < 0 ? 0 : lost);
                return -EBADMSG;
        }
        if (n->n_queue)
                log_info("scan queue: %u plans waiting (%s)", n->n_queue, p);
        return 0;
}

static struct queue_entry *entry_find(struct daemon *d, const char *id, struct queue_entry ***ret_link) {
        for (struct queue_entry **l = &d->night->queue; *l; l = &(*l)->next)
                if (!strcmp((*l)->id, id)) {
                        if (ret_link)
                                *ret_link = l;
                        return *l;
                }
        return NULL;
}

/* Why the queue does not start its next entry now, or NULL when it may. */
static const char *queue_blocked(struct daemon *d, char *buf, size_t size) {
        if (d->stopping)
                return "the daemon is stopping";
        if (d->night->queue_broken)
                return "queue.json is damaged";
        if (!d->have_rig)
                return "the rig is not calibrated";
        if (d->active) {
                snprintf(buf, size, "session %s is %s", d->active->id, session_state_name(d->active->state));
                return buf;
        }
        for (struct session *s = d->sessions; s; s = s->next)
                if (s->state == SESSION_PAUSED) {
                        snprintf(buf, size, "session %s is paused%s: resume or abort it first", s->id,
                                 s->interrupted ? " (interrupted)" : "");
                        return buf;
                }
        if (d->probe)
                return "the devices are being probed";
        return NULL;
}

static int queue_start_next(sd_event_source *src, void *userdata) {
        struct daemon *d = userdata;
        struct night *n = d->night;
        char why[256];
        struct queue_entry **link = &n->queue, *q;
        while (*link && (*link)->error[0])
                link = &(*link)->next;
        if (!(q = *link) || queue_blocked(d, why, sizeof why))
                return 0;
        _cleanup_proto_error_ struct imp_proto_error e = { 0 };
        char planp[PATH_MAX];
        struct session *s = NULL;
        int r = plan_path_resolve(d, &q->peer, q->plan, "plan", planp, &e);
        if (r >= 0)
                r = session_start(d, planp, q->name, &s, &e);
        if (r < 0) {
                snprintf(q->error, sizeof q->error, "%s: %.400s", imp_proto_error_code_name(e.code),
                         e.message);
                log_error("scan queue: %s (%s): could not start: %s; going on with the next plan", q->id, q->plan,
                          q->error);
                (void) queue_save(d);
                queue_kick(d);          /* the next entry, if any */
                return 0;
        }
        (void) calibration_reference_set(d, s->dir, &(struct imp_error) { 0 });
        log_info("scan queue: %s started as session %s (plan %s, queued %s by uid %u)", q->id, s->id, q->plan,
                 q->added, (unsigned) q->peer.uid);
        night_session_log(d, s->id, "started from the scan queue: entry %s, plan %s, queued %s by uid %u", q->id,
                          q->plan, q->added, (unsigned) q->peer.uid);
        *link = q->next;
        n->n_queue--;
        free(q);
        (void) queue_save(d);
        return 0;
}

void queue_kick(struct daemon *d) {
        struct night *n = d->night;
        if (!n || !n->queue || d->stopping)
                return;
        /* from the loop, never from inside the session code that freed the rig */
        if (!n->queue_defer && sd_event_add_defer(d->event, &n->queue_defer, queue_start_next, d) < 0)
                return;
        (void) sd_event_source_set_enabled(n->queue_defer, SD_EVENT_ONESHOT);
}

static json_t *queue_changed(struct daemon *d, json_t *result, const char *why) {
        if (queue_save(d) < 0) {
                json_decref(result);
                return NULL;
        }
        queue_kick(d);
        return result;
}

json_t *queue_add(struct daemon *d, const struct daemon_peer *peer, const char *plan, const char *name,
                  struct imp_proto_error *e) {
        struct night *n = d->night;
        char planp[PATH_MAX];
        struct imp_plan *p = NULL;
        if (n->queue_broken)
                return imp_proto_error_set(e, IMP_PROTO_E_IO, EBADMSG, NULL, "%s/queue.json is damaged (see the "
                                           "journal); fix or remove it and restart impastod", d->state_dir), NULL;
        if (n->n_queue >= NIGHT_QUEUE_MAX)
                return imp_proto_error_set(e, IMP_PROTO_E_BUSY, ENOSPC, NULL, "the scan queue is full (%d plans)",
                                           NIGHT_QUEUE_MAX), NULL;
        if (plan_path_resolve(d, peer, plan, "args.plan", planp, e) < 0 || plan_check(d, planp, &p, e) < 0)
                return NULL;
        imp_plan_free(p);
        struct queue_entry *q = calloc(1, sizeof *q);
        if (!q)
                return imp_proto_error_set(e, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory"), NULL;
        snprintf(q->id, sizeof q->id, "q%u", n->queue_next_id++);
        snprintf(q->plan, sizeof q->plan, "%s", planp);
        snprintf(q->name, sizeof q->name, "%s", name ? name : "session");
        rfc3339_now(q->added);
        q->peer = *peer;
        unsigned pos = 1;
        struct queue_entry **l = &n->queue;
        for (; *l; l = &(*l)->next)
                pos++;
        *l = q;
        n->n_queue++;
        char why[256];
        const char *blocked = queue_blocked(d, why, sizeof why);
        json_t *res = entry_json(q, pos);
        json_object_set_new(res, "waiting_for", blocked ? json_string(blocked) : json_null());
        return queue_changed(d, res, "added");
}

json_t *queue_list_json(struct daemon *d) {
        json_t *a = json_array();
        unsigned pos = 1;
        for (struct queue_entry *q = d->night->queue; q; q = q->next)
                json_array_append_new(a, entry_json(q, pos++));
        char why[256];
        const char *blocked = d->night->queue ? queue_blocked(d, why, sizeof why) : NULL;
        return json_pack("{s:o, s:s?}", "queue", a, "waiting_for", blocked);
}

json_t *queue_move(struct daemon *d, const char *id, int pos, struct imp_proto_error *e) {
        struct queue_entry **link, *q = entry_find(d, id, &link);
        if (!q)
                return imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.id", "no queue entry %s", id), NULL;
        *link = q->next;
        struct queue_entry **l = &d->night->queue;
        for (int i = 1; *l && i < pos; i++)
                l = &(*l)->next;
        q->next = *l;
        *l = q;
        q->error[0] = 0;                /* moved: the operator tries it again */
        return queue_changed(d, queue_list_json(d), "moved");
}

json_t *queue_cancel(struct daemon *d, const char *id, struct imp_proto_error *e) {
        struct queue_entry **link, *q = entry_find(d, id, &link);
        if (!q)
                return imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.id", "no queue entry %s", id), NULL;
        json_t *res = json_pack("{s:s, s:s, s:s}", "id", q->id, "plan", q->plan, "state", "cancelled");
        *link = q->next;
        d->night->n_queue--;
        free(q);
        return queue_changed(d, res, "cancelled");
}

/* For `status`: entries that could not start, with what to do. */
void queue_attention(struct daemon *d, json_t *list) {
        struct night *n = d->night;
        if (n->queue_damaged[0] || n->queue_broken) {
                char msg[1200], action[PATH_MAX + 200];
                snprintf(msg, sizeof msg, "the scan queue file was damaged: %s",
                         n->queue_damaged[0] ? n->queue_damaged : "it could not be moved aside; the queue is stopped");
                snprintf(action, sizeof action, "%s: re-add the plans it held with impasto queue add PLAN --name NAME, "
                         "then remove the damaged file (it stays listed here until impastod restarts)",
                         n->queue_broken ? "fix or remove STATE/queue.json and restart impastod" : "read the file kept aside");
                json_array_append_new(list, json_pack("{s:s, s:s, s:s}", "kind", "queue_damaged", "message", msg,
                                                      "action", action));
        }
        for (struct queue_entry *q = d->night->queue; q; q = q->next)
                if (q->error[0]) {
                        char action[128];
                        snprintf(action, sizeof action, "impasto queue move %s 1 (to try again) or impasto queue cancel %s",
                                 q->id, q->id);
                        json_array_append_new(list, json_pack("{s:s, s:s, s:s, s:s}", "kind", "queue_failed", "id", q->id,
                                                              "message", q->error, "action", action));
                }
}

void queue_free(struct daemon *d) {
        struct night *n = d->night;
        while (n->queue) {
                struct queue_entry *q = n->queue;
                n->queue = q->next;
                free(q);
        }
        n->n_queue = 0;
        n->queue_defer = sd_event_source_disable_unref(n->queue_defer);
}
