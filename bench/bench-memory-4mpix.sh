#!/usr/bin/env bash
# Peak memory of `impasto process` on a 4-Mpix capture with 3 exposures (issue #4: "a 4-Mpix
# capture with 3 exposures processes within 2 GiB"). Renders config/scenes/bench-4mpix.cfg
# (the demo scene seen by a 2304 x 1728 camera; direct light and projector patterns only)
# with config/plans/bench-4mpix.cfg (Gray code + 4-step phase, 3 exposures: 150 frames;
# 12 dome lights x 3 exposures: 36 frames) once, then processes it twice under
# /usr/bin/time -v: the geometry stages alone (--no-btf --no-photometric-normals) and the
# whole job. Prints peak RSS against the 2 GiB budget, wall and CPU seconds, and throughput
# in input Mpix/s (frames x camera pixels / wall second) and camera Mpix/s.
#
# Usage: bench/bench-memory-4mpix.sh [-B build-dir] [-o out-dir] [-f] [-g]
#   -f  render again even when out-dir/capture exists     -g  geometry only
set -euo pipefail

here=$(cd "$(dirname "$0")" && pwd)
src=$here/..
build=${IMPASTO_BUILD:-$src/build} out=$src/out/bench-4mpix force=0 geometry_only=0
while getopts "B:o:fg" opt; do
        case $opt in
        B) build=$OPTARG ;; o) out=$OPTARG ;; f) force=1 ;; g) geometry_only=1 ;;
        *) sed -n '2,13p' "$0"; exit 2 ;;
        esac
done
impasto=$build/cli/impasto
for tool in "$impasto" /usr/bin/time python3; do
        command -v "$tool" >/dev/null || { echo "bench-memory-4mpix: $tool missing, skipping" >&2; exit 77; }
done
scene=$src/config/scenes/bench-4mpix.cfg plan=$src/config/plans/bench-4mpix.cfg
budget_mib=2048
mkdir -p "$out"

if [[ $force == 1 || ! -f $out/capture/manifest.jsonl ]]; then
        rm -rf "$out/capture"
        echo "rendering $(basename "$scene") with $(basename "$plan") into $out/capture ..."
        /usr/bin/time -v "$impasto" sim render --scene "$scene" --plan "$plan" --out "$out/capture" --quiet \
                2> "$out/render.time"
fi
frames=$(wc -l < "$out/capture/manifest.jsonl")

# run NAME ARGS...: processes the capture into $out/copy-NAME and prints one line.
run() {
        local name=$1
        shift
        rm -rf "$out/copy-$name"
        if ! /usr/bin/time -v "$impasto" process "$out/capture" --out "$out/copy-$name" --quiet "$@" \
                > "$out/process-$name.log" 2> "$out/process-$name.time"; then
                echo "bench-memory-4mpix: impasto process ($name) failed:" >&2
                cat "$out/process-$name.log" "$out/process-$name.time" >&2
                return 1
        fi
        python3 - "$out" "$name" "$frames" "$budget_mib" <<'EOF'
import json, sys
out, name, frames, budget = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
t = open(f"{out}/process-{name}.time").read()
def num(key):   # "\tMaximum resident set size (kbytes): 940652": the text after the last ": "
    line = next(l for l in t.splitlines() if l.strip().startswith(key))
    return line.rsplit(": ", 1)[1].strip()
rss_mib = float(num("Maximum resident set size")) / 1024
wall = num("Elapsed (wall clock) time")
parts = [float(p) for p in wall.split(":")]
wall_s = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
cpu_s = float(num("User time")) + float(num("System time"))
rig = json.load(open(f"{out}/capture/rig.json"))
cam = rig["cameras"][0]["model"]
mpix = cam["width"] * cam["height"] / 1e6
used = [l for l in open(f"{out}/capture/manifest.jsonl")]
if name == "geometry":
    frames = sum(1 for l in used if json.loads(l).get("step") == "structured-light")
verdict = "within" if rss_mib <= budget else "OVER"
print(f"{name:9s} {frames:4d} frames of {mpix:.2f} Mpix: peak RSS {rss_mib:7.1f} MiB "
      f"({100 * rss_mib / budget:5.1f} % of {budget:.0f} MiB, {verdict} budget), wall {wall_s:6.1f} s, "
      f"CPU {cpu_s:6.1f} s, {frames * mpix / wall_s:6.1f} input Mpix/s "
      f"({frames * mpix / cpu_s:6.1f} per CPU s), {mpix / wall_s:5.3f} camera Mpix/s")
EOF
}

echo "machine: $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg)"
run geometry --no-btf --no-photometric-normals
[[ $geometry_only == 1 ]] || run full
echo "machine after: load average $(cut -d' ' -f1-3 /proc/loadavg)"
