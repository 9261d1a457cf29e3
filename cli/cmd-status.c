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
        if (json_is_object(j))
                printf("jobs     %lld queued, %lld running\n", imp_client_int(j, "queued"),
                       imp_client_int(j, "running"));
        /* the newest finished copy's quality verdict, when the copy has one */
        const json_t *last = json_object_get(j, "last_done");
        if (json_is_object(last) && *imp_client_str(last, "verdict"))
                printf("copy     %s: verdict %s\n", imp_client_str(last, "job"), imp_client_str(last, "verdict"));
}

static int run(int argc, char **argv) {
        return imp_client_main_simple(argc, argv, "status", human);
}

const struct imp_command imp_cmd_status = {
        .name = "status",
        .summary = "the daemon, the rig, the running session and the job queue",
        .run = run,
};
