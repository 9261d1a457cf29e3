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
}

static int run(int argc, char **argv) {
        return imp_client_main_simple(argc, argv, "devices", human);
}

const struct imp_command imp_cmd_devices = {
        .name = "devices",
        .summary = "the rig's cameras, projector, dome and trigger with their state",
        .run = run,
};
