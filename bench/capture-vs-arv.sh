#!/usr/bin/env bash
# GigE Vision capture, impasto's Aravis backend (bench-aravis) vs arv-camera-test-0.8, on the
# same emulated camera (arv-fake-gv-camera-0.8 on 127.0.0.1): same size, pixel format and
# AcquisitionFrameRate, same duration, alternating order, R repetitions. Counts frames
# received, lost and incomplete, and each client's CPU time (GNU time: user+sys, peak RSS).
#
# Runs in a private network namespace (unshare -n) when it can, so that it neither waits
# for nor disturbs other users of UDP 127.0.0.1:3956; otherwise on the host's loopback,
# waiting until the port is free.
#
# Usage: bench/capture-vs-arv.sh [-B build-dir] [-d seconds] [-r reps] [-W width] [-H height]
#                                [-p Mono8|Mono16] [-f fps] [-b impasto-buffers] [-o results.tsv]
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
build=${IMPASTO_BUILD:-$here/../build}
duration=10 reps=3 width=1024 height=1024 format=Mono8 fps=30 buffers=0 out=
while getopts "B:d:r:W:H:p:f:b:o:" opt; do
        case $opt in
        B) build=$OPTARG ;; d) duration=$OPTARG ;; r) reps=$OPTARG ;;
        W) width=$OPTARG ;; H) height=$OPTARG ;; p) format=$OPTARG ;; f) fps=$OPTARG ;;
        b) buffers=$OPTARG ;; o) out=$OPTARG ;;
        *) sed -n '2,13p' "$0"; exit 2 ;;
        esac
done
bench=$build/bench/bench-aravis
for tool in "$bench" arv-camera-test-0.8 arv-fake-gv-camera-0.8 arv-tool-0.8 /usr/bin/time; do
        command -v "$tool" >/dev/null || { echo "capture-vs-arv: $tool missing, skipping" >&2; exit 77; }
done

# Re-enter in a private network namespace with only lo up.
if [[ -z ${IMPASTO_BENCH_NETNS:-} ]] && unshare -n true 2>/dev/null; then
        export IMPASTO_BENCH_NETNS=1
        exec unshare -n bash -c 'ip link set lo up && exec "$0" "$@"' "$0" "$@"
fi

addr=127.0.0.1
port_busy() { ss -Huln "src $addr:3956" 2>/dev/null | grep -q .; }
for _ in $(seq 120); do port_busy || break; sleep 1; done
port_busy && { echo "capture-vs-arv: UDP $addr:3956 stays busy, skipping" >&2; exit 77; }

work=$(mktemp -d)
cam_pid=
cleanup() { [[ -n $cam_pid ]] && kill "$cam_pid" 2>/dev/null; wait 2>/dev/null; rm -rf "$work"; }
trap cleanup EXIT
arv-fake-gv-camera-0.8 -i "$addr" -s BENCH01 >"$work/camera.log" 2>&1 &
cam_pid=$!
for _ in $(seq 50); do arv-tool-0.8 -a "$addr" control DeviceModelName >/dev/null 2>&1 && break; sleep 0.2; done

# utime + stime of a process in seconds (/proc/PID/stat fields 14 and 15).
proc_cpu_s() { awk -v hz="$(getconf CLK_TCK)" '{ print ($14 + $15) / hz }' "/proc/$1/stat"; }

configure_camera() {
        arv-tool-0.8 -a "$addr" control Width="$width" Height="$height" PixelFormat="$format" \
                AcquisitionFrameRate="$fps" >/dev/null
}

timefmt='time_user_s=%U time_sys_s=%S time_maxrss_kb=%M'

# Each run prints: client fps frames lost incomplete underruns cpu_s cpu_ms_per_frame rss_kb camera_cpu_s
run_impasto() {
        configure_camera
        local c0 c1 line
        c0=$(proc_cpu_s "$cam_pid")
        line=$(/usr/bin/time -f "$timefmt" -o "$work/time" "$bench" --address "$addr" \
                --duration-s "$duration" --buffers "$buffers")
        c1=$(proc_cpu_s "$cam_pid")
        echo "$line" >>"$work/raw.log"
        echo "$line $(cat "$work/time") camera_cpu_s=$(awk -v a="$c0" -v b="$c1" 'BEGIN{print b-a}')" |
                awk '{ for (i = 1; i <= NF; i++) { split($i, kv, "="); v[kv[1]] = kv[2] }
                       cpu = v["time_user_s"] + v["time_sys_s"]
                       printf "impasto %.2f %d %d %d %d %.2f %.3f %d %.2f\n", v["fps"], v["frames"],
                              v["lost"], v["incomplete"], v["underruns"], cpu,
                              1000 * cpu / v["frames"], v["time_maxrss_kb"], v["camera_cpu_s"] }'
}

run_arv() {
        configure_camera
        local c0 c1
        c0=$(proc_cpu_s "$cam_pid")
        /usr/bin/time -f "$timefmt" -o "$work/time" arv-camera-test-0.8 -n "$addr" -a \
                -w "$width" -h "$height" -f "$fps" --duration="$duration" >"$work/arv.log" 2>&1
        c1=$(proc_cpu_s "$cam_pid")
        cat "$work/arv.log" >>"$work/raw.log"
        { tr -s ' ' <"$work/arv.log" | sed -n 's/^\(n_[a-z_]*\) = \([0-9]*\)$/\1=\2/p'
          tr ' ' '\n' <"$work/time"; echo "camera_cpu_s=$(awk -v a="$c0" -v b="$c1" 'BEGIN{print b-a}')"; } |
                awk -v d="$duration" -F= '{ v[$1] = $2 }
                     END { n = v["n_completed_buffers"]; cpu = v["time_user_s"] + v["time_sys_s"]
                           printf "arv %.2f %d %d %d %d %.2f %.3f %d %.2f\n", n / d, n,
                                  v["n_missing_frames"], v["n_failures"] + v["n_size_mismatch_errors"],
                                  v["n_underruns"], cpu, n ? 1000 * cpu / n : 0,
                                  v["time_maxrss_kb"], v["camera_cpu_s"] }'
}

echo "# capture-vs-arv: ${width}x${height} $format at AcquisitionFrameRate=$fps, ${duration} s x $reps," \
     "impasto buffers=${buffers/#0/4 (default)}, netns=${IMPASTO_BENCH_NETNS:-0}, $(nproc) cores," \
     "load $(cut -d' ' -f1-3 /proc/loadavg)"
printf '%-8s %8s %7s %5s %10s %9s %7s %11s %9s %12s\n' client fps frames lost incomplete underruns \
        cpu_s cpu_ms/frame rss_kb camera_cpu_s
: >"$work/results"
for ((rep = 1; rep <= reps; rep++)); do
        if ((rep % 2)); then order="run_impasto run_arv"; else order="run_arv run_impasto"; fi
        for run in $order; do
                $run | tee -a "$work/results" |
                        awk '{ printf "%-8s %8.2f %7d %5d %10d %9d %7.2f %11.3f %9d %12.2f\n", $1, $2, $3, $4, $5, $6, $7, $8, $9, $10 }'
        done
done
[[ -n $out ]] && cp "$work/results" "$out"

# Medians (and min..max) per client, then the ratio of the medians.
awk '
function median(a, n,   i, j, t) {
        for (i = 2; i <= n; i++) for (j = i; j > 1 && a[j - 1] > a[j]; j--) { t = a[j]; a[j] = a[j - 1]; a[j - 1] = t }
        return n % 2 ? a[(n + 1) / 2] : (a[n / 2] + a[n / 2 + 1]) / 2
}
{ k = $1; n[k]++; fps[k, n[k]] = $2; cpf[k, n[k]] = $8; lost[k] += $4; inc[k] += $5; und[k] += $6
  rss[k] = $9 > rss[k] ? $9 : rss[k]
  lo[k] = (n[k] == 1 || $2 < lo[k]) ? $2 : lo[k]; hi[k] = $2 > hi[k] ? $2 : hi[k] }
END {
        for (k in n) {
                delete f; delete c
                for (i = 1; i <= n[k]; i++) { f[i] = fps[k, i]; c[i] = cpf[k, i] }
                mf[k] = median(f, n[k]); mc[k] = median(c, n[k])
                printf "%-8s median %.2f fps (%.2f..%.2f), %.3f ms CPU/frame, lost %d, incomplete %d, underruns %d, peak RSS %d kB\n",
                       k, mf[k], lo[k], hi[k], mc[k], lost[k], inc[k], und[k], rss[k]
        }
        if (mf["arv"] > 0)
                printf "ratio impasto/arv-camera-test: frame rate %.3f, CPU per frame %.2f\n",
                       mf["impasto"] / mf["arv"], (mc["arv"] > 0 ? mc["impasto"] / mc["arv"] : 0)
}' "$work/results"
