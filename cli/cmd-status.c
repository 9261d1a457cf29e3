/* `impasto status [--json] [--socket PATH]`: the daemon, the rig, the session in progress
 * and the job queue at a glance (the `status` command of proto/PROTOCOL.md). */
#include <stdio.h>
#include "client.h"
#include "commands.h"

static void human(const json_t *r) {
        const json_t *d = json_object_get(r, "daemon"), *rig = json_object_get(r, "rig");
        const json_t *s = json_object_get(r, "session"), *j = json_object_get(r, "jobs");
        char up[32];
        printf("daemon   impastod %s, pid %lld, up %s\n", imp_client_str(d, "version"),
               imp_client_int(d, "pid"), imp_client_fmt_duration(imp_client_num(d, "uptime_s"), up, sizeof up));
        if (json_is_object(rig))
                printf("rig      %s, %s\n", imp_client_str(rig, "name"),
                       json_is_true(json_object_get(rig, "calibrated")) ? "calibrated" : "NOT calibrated");
        if (json_is_object(s))
                printf("session  %s: %s, step %lld of %lld\n", imp_client_str(s, "session"),
                       imp_client_str(s, "state"), imp_client_int(s, "step"), imp_client_int(s, "steps"));
        else
                printf("session  none\n");
        imp_client_print_painting(json_object_get(s, "painting"));
        if (json_is_object(j))
                printf("jobs     %lld queued, %lld running, %lld failed\n", imp_client_int(j, "queued"),
                       imp_client_int(j, "running"), imp_client_int(j, "failed"));
        const json_t *q = json_object_get(r, "queue");
        if (imp_client_int(q, "entries") > 0)
                printf("queue    %lld plans%s%s\n", imp_client_int(q, "entries"),
                       *imp_client_str(q, "waiting_for") ? ", waiting: " : "", imp_client_str(q, "waiting_for"));
        /* the newest finished copy's quality verdict, when the copy has one */
        const json_t *last = json_object_get(j, "last_done");
        if (json_is_object(last) && *imp_client_str(last, "verdict"))
                printf("copy     %s: verdict %s\n", imp_client_str(last, "job"), imp_client_str(last, "verdict"));
        imp_client_print_attention(json_object_get(r, "attention"));
}

/* What needs the operator (status, report): each item and the command that acts on it. */
void imp_client_print_painting(const json_t *p) {
        if (!json_is_object(p))
                return;
        char tile_eta[32], eta[32];
        printf("painting tile %lld of %lld (%lld done), frame %lld of %lld in it, tile ETA %s, painting ETA %s\n",
               imp_client_int(p, "tile") + 1, imp_client_int(p, "tiles"), imp_client_int(p, "tiles_done"),
               imp_client_int(p, "tile_frames_done"), imp_client_int(p, "tile_frames"),
               imp_client_fmt_duration(imp_client_num(p, "tile_eta_s"), tile_eta, sizeof tile_eta),
               imp_client_fmt_duration(imp_client_num(p, "eta_s"), eta, sizeof eta));
        if (json_is_string(json_object_get(p, "stage")))
                printf("stage    %s\n", imp_client_str(p, "stage"));
}

void imp_client_print_attention(const json_t *att) {
        const json_t *items = json_object_get(att, "items"), *it;
        size_t i;
        if (!json_array_size(items)) {
                printf("state    ok: nothing needs attention\n");
                return;
        }
        printf("state    DEGRADED: %zu item%s need%s attention\n", json_array_size(items) + (size_t) imp_client_int(att, "more"),
               json_array_size(items) == 1 ? "" : "s", json_array_size(items) == 1 ? "s" : "");
        json_array_foreach(items, i, it) {
                printf("  ! %s\n", imp_client_str(it, "message"));
                printf("    -> %s\n", imp_client_str(it, "action"));
        }
        if (imp_client_int(att, "more") > 0)
                printf("  … and %lld more (impasto report --since 7d)\n", imp_client_int(att, "more"));
}

static int run(int argc, char **argv) {
        return imp_client_main_simple(argc, argv, "status", human);
}

const struct imp_command imp_cmd_status = {
        .name = "status",
        .summary = "the daemon, the rig, the running session and the job queue",
        .run = run,
};
