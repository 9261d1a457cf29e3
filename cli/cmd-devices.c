/* `impasto devices [--json] [--socket PATH]`: every device of the rig config with its
 * backend and state (the `devices` command of proto/PROTOCOL.md). */
#include <stdio.h>
#include "client.h"
#include "commands.h"

static void human(const json_t *r) {
        const json_t *list = json_object_get(r, "devices"), *d;
        size_t i;
        if (!json_array_size(list)) {
                printf("no devices configured\n");
                return;
        }
        printf("%-12s %-10s %-10s %-7s %s\n", "NAME", "CLASS", "BACKEND", "STATE", "DETAIL");
        json_array_foreach(list, i, d)
                printf("%-12s %-10s %-10s %-7s %s\n", imp_client_str(d, "name"), imp_client_str(d, "class"),
                       imp_client_str(d, "backend"), imp_client_str(d, "state"), imp_client_str(d, "detail"));
        /* a probe opens and reads each device; otherwise the state is as impastod last saw it */
        const json_t *age = json_object_get(r, "age_s");
        char buf[32];
        if (json_is_true(json_object_get(r, "probed")))
                printf("(probed now: each device opened and read)\n");
        else if (json_is_number(age))
                printf("(as last known, probed %s ago; not probed now: a session holds the rig, an observer's\n"
                       " request, or the last probe is under --device-probe-interval-s old)\n",
                       imp_client_fmt_duration(json_number_value(age), buf, sizeof buf));
        else if (json_object_get(r, "probed"))
                printf("(as last known, never probed since impastod started: an operator's impasto devices probes)\n");
}

static int run(int argc, char **argv) {
        return imp_client_main_simple(argc, argv, "devices", human);
}

const struct imp_command imp_cmd_devices = {
        .name = "devices",
        .summary = "the rig's cameras, projector, dome and trigger with their state",
        .run = run,
};
