#!/usr/bin/env bash
# Capture to disk through impastod vs arv-camera-test-0.8 on the same emulated GigE camera
# (arv-fake-gv-camera-0.8 on 127.0.0.1). impastod runs a dome-sweep plan of N frames
# (L lights x E exposures; software trigger per frame, 16-bit TIFF + manifest, fsynced, as
# docs/daemon.md describes) started with `impasto scan start PLAN --wait`; the peer streams
# the same size and Mono16 free-running at the camera's highest AcquisitionFrameRate
# for about as long, without writing anything. Reported: frames/s and MiB/s of each, their
# ratio (MiB/s counts pixel bytes, w x h x 2 per frame; the TIFFs on disk are compressed,
# their own rate is printed as stored_mib_s), frames the plan asked for but the set lacks, and impastod's CPU and peak RSS
# (VmHWM). The rig has no dome controller, so the plan's light switching costs nothing
# here: what is measured is camera -> daemon -> disk. A second peer run, arv-camera-test
# with software triggers (-o 1000, "arv-trig"), shows what the camera gives a triggering
# client at all.
#
# Camera (-c): "arv" is arv-fake-gv-camera-0.8, whose software trigger is polled at 25 Hz
# (no triggered client gets more than 25 frames/s from it); "fast" is bench-fake-camera
# (the same Aravis fake camera, trigger polled at 1 kHz; free running it is identical).
# -D runs another impastod binary (e.g. an older build, for before/after runs side by side).
#
# Plan (-m): "sweep" (the default) is the dome sweep above, every frame software-triggered;
# "stream" is one light at one exposure repeated N times (-n, default 240:
# `dome = { lights = [0]; exposures_us = [E]; repeat = N; }`), a constant-state run that the
# daemon captures with the camera free-running (docs/daemon.md, "Streamed runs"); its peer
# is arv-camera-test free-running at the same AcquisitionFrameRate (no arv-trig run). -f sets
# the camera's AcquisitionFrameRate for the daemon and the peers (default 1000: as fast as
# the emulator goes). The daemon's streamed-run counts (frames lost in the stream and
# re-captured, stale frames discarded, runs cut by a full store queue) come from its log.
#
# Runs in a private network namespace (unshare -n) when it can (see capture-vs-arv.sh).
#
# Usage: bench/bench-capture-daemon.sh [-B build-dir] [-r reps] [-W width] [-H height]
#                                      [-l lights] [-e exposures_us,...] [-s state-parent-dir]
#                                      [-c arv|fast] [-D impastod] [-m sweep|stream] [-n frames]
#                                      [-f fps]
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
build=${IMPASTO_BUILD:-$here/../build}
reps=3 width=1024 height=1024 lights=60 exposures=1000,2000 state_parent=${TMPDIR:-/tmp} camera=arv daemon=
mode=sweep repeat=240 fps=1000
while getopts "B:r:W:H:l:e:s:c:D:m:n:f:" opt; do
        case $opt in
        B) build=$OPTARG ;; r) reps=$OPTARG ;; W) width=$OPTARG ;; H) height=$OPTARG ;;
        l) lights=$OPTARG ;; e) exposures=$OPTARG ;; s) state_parent=$OPTARG ;;
        c) camera=$OPTARG ;; D) daemon=$OPTARG ;; m) mode=$OPTARG ;; n) repeat=$OPTARG ;; f) fps=$OPTARG ;;
        *) sed -n '2,36p' "$0"; exit 2 ;;
        esac
done
case $mode in
sweep|stream) ;;
*) echo "bench-capture-daemon: -m: expected sweep or stream" >&2; exit 2 ;;
esac
daemon=${daemon:-$build/daemon/impastod} client=$build/cli/impasto
case $camera in
arv) camera_cmd=(arv-fake-gv-camera-0.8) ;;
fast) camera_cmd=("$build/bench/bench-fake-camera" -t 1000) ;;
*) echo "bench-capture-daemon: -c: expected arv or fast" >&2; exit 2 ;;
esac
for tool in "$daemon" "$client" "${camera_cmd[0]}" arv-camera-test-0.8 arv-tool-0.8 /usr/bin/time python3; do
        command -v "$tool" >/dev/null || { echo "bench-capture-daemon: $tool missing, skipping" >&2; exit 77; }
done

if [[ -z ${IMPASTO_BENCH_NETNS:-} ]] && unshare -n true 2>/dev/null; then
        export IMPASTO_BENCH_NETNS=1
        exec unshare -n bash -c 'ip link set lo up && exec "$0" "$@"' "$0" "$@"
fi

addr=127.0.0.1
port_busy() { ss -Huln "src $addr:3956" 2>/dev/null | grep -q .; }
for _ in $(seq 120); do port_busy || break; sleep 1; done
port_busy && { echo "bench-capture-daemon: UDP $addr:3956 stays busy, skipping" >&2; exit 77; }

work=$(mktemp -d "$state_parent/impasto-bench-capture.XXXXXX")
cam_pid= daemon_pid=
cleanup() {
        [[ -n $daemon_pid ]] && kill "$daemon_pid" 2>/dev/null
        [[ -n $cam_pid ]] && kill "$cam_pid" 2>/dev/null
        wait 2>/dev/null; rm -rf "$work"
}
trap cleanup EXIT
"${camera_cmd[@]}" -i "$addr" -s BENCH02 >"$work/camera.log" 2>&1 &
cam_pid=$!
for _ in $(seq 50); do arv-tool-0.8 -a "$addr" control DeviceModelName >/dev/null 2>&1 && break; sleep 0.2; done

# Rig: one camera of the requested size, 16-bit, `lights` dome lights on a ring, no settle.
python3 - "$work/rig.json" "$width" "$height" "$lights" <<'EOF'
import json, math, sys
path, w, h, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
lights = [{"id": i, "pos_mm": [400 * math.cos(2 * math.pi * i / n), 400 * math.sin(2 * math.pi * i / n), 300],
           "intensity": 1.0, "colour": [1.0, 1.0, 1.0], "axis": [0.0, 0.0, -1.0], "profile_exp": 0.0} for i in range(n)]
cam = {"name": "cam0",
       "model": {"width": w, "height": h, "fx": 5000.0, "fy": 5000.0, "cx": w / 2, "cy": h / 2,
                 "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "k3": 0.0,
                 "R": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], "t": [0.0, 0.0, 500.0]},
       "sensor": {"bits": 16, "black_level_dn": 0.0, "gain_e_per_dn": 1.0, "read_noise_e": 0.0,
                  "full_well_e": 65535.0, "dark_current_e_per_s": 0.0, "prnu": 0.0,
                  "quantum_scale": 1.0, "readout_us": 0.0, "bayer": False}}
json.dump({"format": "impasto-rig", "version": 1, "cameras": [cam], "lights": lights, "settle_us": 0.0},
          open(path, "w"), indent=1)
EOF
cat >"$work/rig.cfg" <<EOF
rig = {
  name = "bench";
  calibration = "rig.json";
  cameras = ( { name = "cam0"; backend = "aravis"; address = "$addr"; } );
};
EOF
exp_list=$(echo "$exposures" | sed 's/\([0-9.]*\)/\1.0/g; s/\.0\.0/.0/g; s/,/, /g')
n_exp=$(echo "$exposures" | tr ',' '\n' | grep -c .)
if [[ $mode == sweep ]]; then
        cat >"$work/plan.cfg" <<EOF
# Dome sweep: every light, each with an exposure stack.
dome = {
  lights = "all";
  exposures_us = [$exp_list];
};
EOF
        n_frames=$((lights * n_exp))
        plan_desc="${lights} lights x ${n_exp} exposures"
else
        first_exp=$(echo "$exp_list" | cut -d, -f1)
        cat >"$work/plan.cfg" <<EOF
# One constant-state run: light 0 at one exposure, $repeat frames (streamed).
dome = { lights = [0]; exposures_us = [$first_exp]; repeat = $repeat; };
EOF
        n_frames=$repeat
        plan_desc="1 light x 1 exposure ($first_exp us) x repeat $repeat (streamed)"
fi
frame_mib=$(awk -v w="$width" -v h="$height" 'BEGIN { print w * h * 2 / 1048576 }')

proc_cpu_s() { awk -v hz="$(getconf CLK_TCK)" '{ print ($14 + $15) / hz }' "/proc/$1/stat"; }
now_s() { date +%s.%N; }

# Prints: daemon fps mib_s frames_stored missing cpu_s cpu_ms_per_frame vmhwm_kb state
#         stored_mib_s wall_s lost stale stops
run_daemon() {
        local rep=$1 state=$work/state-$rep sock=$work/control-$rep.sock
        mkdir -p "$state"
        # The same camera setting as the peer's (the daemon sets size, format and trigger).
        arv-tool-0.8 -a "$addr" control AcquisitionFrameRate="$fps" >/dev/null
        "$daemon" --rig "$work/rig.cfg" --socket "$sock" --state-dir "$state" --operators-all \
                --worker-cmd /bin/true --min-free-bytes 0 2>"$work/daemon-$rep.log" &
        daemon_pid=$!
        for _ in $(seq 100); do [[ -S $sock ]] && break; sleep 0.1; done
        # Devices open on first use: open them before the clock starts.
        "$client" devices --socket "$sock" >/dev/null 2>&1 || true
        local c0 c1 t0 t1 rc=0
        c0=$(proc_cpu_s "$daemon_pid"); t0=$(now_s)
        "$client" scan start "$work/plan.cfg" --name "bench$rep" --wait --socket "$sock" \
                >"$work/scan-$rep.log" 2>&1 || rc=$?
        t1=$(now_s); c1=$(proc_cpu_s "$daemon_pid")
        if ((rc != 0)); then
                echo "bench-capture-daemon: scan exited $rc:" >&2
                tail -n 5 "$work/scan-$rep.log" "$work/daemon-$rep.log" >&2
        fi
        local hwm set stored bytes streamed
        hwm=$(awk '/^VmHWM/ { print $2 }' "/proc/$daemon_pid/status")
        kill "$daemon_pid"; wait "$daemon_pid" 2>/dev/null || true; daemon_pid=
        # "…; streamed F frames in R runs, L lost and re-captured, S stale discarded, T runs cut …"
        streamed=$(sed -n 's/.*streamed \([0-9]*\) frames in \([0-9]*\) runs, \([0-9]*\) lost.*, \([0-9]*\) stale.*, \([0-9]*\) runs cut.*/\3 \4 \5/p' \
                "$work/daemon-$rep.log" | tail -1)
        set=$(ls -d "$state"/sessions/*/ 2>/dev/null | head -1)
        stored=$( [[ -n $set && -f $set/manifest.jsonl ]] && grep -c . "$set/manifest.jsonl" || echo 0)
        bytes=$( [[ -n $set ]] && du -sb "$set/frames" | cut -f1 || echo 0)
        awk -v t0="$t0" -v t1="$t1" -v c0="$c0" -v c1="$c1" -v n="$stored" -v want="$n_frames" \
            -v b="$bytes" -v hwm="$hwm" -v rc="$rc" -v fm="$frame_mib" -v st="${streamed:-? ? ?}" 'BEGIN {
                wall = t1 - t0; cpu = c1 - c0; split(st, s, " ")
                printf "daemon %.2f %.2f %d %d %.2f %.3f %d %s stored_mib_s=%.2f wall_s=%.2f lost=%s stale=%s stops=%s\n",
                       n / wall, n * fm / wall, n, want - n, cpu, n ? 1000 * cpu / n : 0, hwm,
                       rc == 0 ? "completed" : "exit" rc, b / wall / 1048576, wall, s[1], s[2], s[3] }'
        # Where a frame's time goes: trigger -> frame received, and frame -> next trigger
        # (grab hand-off, TIFF write, fsync, next frame's set-up), medians in ms; frames of a
        # streamed run share the run's t_trigger_ns, so for those the interval between frames
        # received and the rate between the first and the last frame are printed instead.
        [[ -n $set && -f $set/manifest.jsonl ]] && python3 - "$set/manifest.jsonl" "$t0" >&2 <<'PY'
import json, statistics, sys
recs = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
t0_ns = float(sys.argv[2]) * 1e9
trig = [r["t_trigger_ns"] for r in recs if "t_trigger_ns" in r]
frame = [r["t_frame_ns"] for r in recs if "t_frame_ns" in r]
if len(trig) > 1 and len(trig) == len(frame):
    streamed = sum(1 for a, b in zip(trig, trig[1:]) if a == b)
    if streamed < len(trig) // 2:
        lat = [(f - t) / 1e6 for t, f in zip(trig, frame)]
        gap = [(t2 - f) / 1e6 for f, t2 in zip(frame, trig[1:])]
        print("  daemon per frame: trigger->frame median %.1f ms (%.1f..%.1f), frame->next trigger median %.1f ms (%.1f..%.1f)"
              % (statistics.median(lat), min(lat), max(lat), statistics.median(gap), min(gap), max(gap)))
    else:
        iv = [(b - a) / 1e6 for a, b in zip(frame, frame[1:])]
        print("  daemon streamed: scan start -> run start %.0f ms, run start -> first frame %.0f ms, frame interval median %.1f ms"
              " (%.1f..%.1f), first -> last frame %.2f s = %.2f fps, last frame -> scan end see wall_s"
              % ((recs[0]["t_light_on_ns"] - t0_ns) / 1e6, (frame[0] - trig[0]) / 1e6, statistics.median(iv), min(iv),
                 max(iv), (frame[-1] - frame[0]) / 1e9, (len(frame) - 1) / ((frame[-1] - frame[0]) / 1e9)))
        print("  daemon streamed: last frame at %.2f s after scan start" % ((frame[-1] - t0_ns) / 1e9))
PY
        rm -rf "$state"
}

# The peer: Mono16 at the camera's AcquisitionFrameRate (-f), for the daemon's last wall time;
# free running ("arv") or with software triggers at 1 kHz ("arv-trig", -o 1000: as fast as
# the camera takes them, without waiting for each frame as impastod must).
run_arv() {
        local seconds=$1 name=$2 trig=()
        [[ $name == arv-trig ]] && trig=(-o 1000)
        arv-tool-0.8 -a "$addr" control Width="$width" Height="$height" PixelFormat=Mono16 \
                TriggerMode=Off AcquisitionFrameRate="$fps" >/dev/null
        /usr/bin/time -f 'time_user_s=%U time_sys_s=%S time_maxrss_kb=%M' -o "$work/time" \
                arv-camera-test-0.8 -n "$addr" -a -w "$width" -h "$height" -f "$fps" "${trig[@]}" \
                --duration="$seconds" >"$work/arv.log" 2>&1
        { tr -s ' ' <"$work/arv.log" | sed -n 's/^\(n_[a-z_]*\) = \([0-9]*\)$/\1=\2/p'; tr ' ' '\n' <"$work/time"; } |
                awk -v d="$seconds" -v fm="$frame_mib" -v name="$name" -F= '{ v[$1] = $2 }
                     END { n = v["n_completed_buffers"]; cpu = v["time_user_s"] + v["time_sys_s"]
                           printf "%s %.2f %.2f %d %d %.2f %.3f %d %s\n", name, n / d, n * fm / d, n,
                                  v["n_missing_frames"] + v["n_failures"], cpu, n ? 1000 * cpu / n : 0,
                                  v["time_maxrss_kb"], name == "arv" ? "free-run" : "sw-trigger" }'
}

echo "# bench-capture-daemon: ${width}x${height} Mono16 at AcquisitionFrameRate $fps, plan $plan_desc" \
     "= $n_frames frames, camera $camera, daemon $daemon, store $state_parent," \
     "netns=${IMPASTO_BENCH_NETNS:-0}, $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-8s %8s %8s %7s %8s %7s %12s %9s %s\n' client fps MiB/s frames missing cpu_s cpu_ms/frame rss_kb state
: >"$work/results"
seconds=10
for ((rep = 1; rep <= reps; rep++)); do
        if ((rep % 2)); then order="daemon arv arv-trig"; else order="arv-trig arv daemon"; fi
        [[ $mode == stream ]] && order=${order/arv-trig/}
        for who in $order; do
                if [[ $who == daemon ]]; then
                        line=$(run_daemon "$rep")
                        seconds=$(echo "$line" | awk -v n="$n_frames" '{ s = $2 > 0 ? $4 / $2 : 10; print (s < 3 ? 3 : int(s + 0.5)) }')
                else
                        line=$(run_arv "$seconds" "$who")
                fi
                echo "$line" | tee -a "$work/results" |
                        awk '{ printf "%-8s %8.2f %8.2f %7d %8d %7.2f %12.3f %9d %s %s %s %s %s %s\n", $1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13, $14 }'
        done
done

awk '
function median(a, n,   i, j, t) {
        for (i = 2; i <= n; i++) for (j = i; j > 1 && a[j - 1] > a[j]; j--) { t = a[j]; a[j] = a[j - 1]; a[j - 1] = t }
        return n % 2 ? a[(n + 1) / 2] : (a[n / 2] + a[n / 2 + 1]) / 2
}
{ k = $1; n[k]++; fps[k, n[k]] = $2; mib[k, n[k]] = $3; cpf[k, n[k]] = $7; miss[k] += $5
  for (i = 12; i <= 14; i++) if (split($i, kv, "=") == 2 && kv[2] ~ /^[0-9]+$/) extra[k, kv[1]] += kv[2]
  rss[k] = $8 > rss[k] ? $8 : rss[k]; lo[k] = (n[k] == 1 || $2 < lo[k]) ? $2 : lo[k]; hi[k] = $2 > hi[k] ? $2 : hi[k] }
END {
        for (k in n) {
                delete f; delete m; delete c
                for (i = 1; i <= n[k]; i++) { f[i] = fps[k, i]; m[i] = mib[k, i]; c[i] = cpf[k, i] }
                mf[k] = median(f, n[k]); mm[k] = median(m, n[k])
                printf "%-8s median %.2f fps (%.2f..%.2f), %.2f MiB/s, %.3f ms CPU/frame, missing %d, peak RSS %d kB",
                       k, mf[k], lo[k], hi[k], mm[k], median(c, n[k]), miss[k], rss[k]
                if (k == "daemon")
                        printf ", streamed: lost %d, stale %d, runs cut %d", extra[k, "lost"], extra[k, "stale"], extra[k, "stops"]
                printf "\n"
        }
        if (mf["arv"] > 0)
                printf "ratio impastod-to-disk / arv-camera-test free-run: %.3f\n", mf["daemon"] / mf["arv"]
        if (mf["arv-trig"] > 0)
                printf "ratio impastod-to-disk / arv-camera-test software-triggered: %.3f\n", mf["daemon"] / mf["arv-trig"]
        printf "load at the end: %s\n", load
}' load="$(cut -d' ' -f1-3 /proc/loadavg)" "$work/results"
