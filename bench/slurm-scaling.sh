#!/bin/bash
# Scale-out on one node (docs/scale-out.md, "Measured"): N tiles (config/scenes/small.cfg with
# config/plans/small.cfg, seeds 1..N) through a one-node Slurm (tests/integration/lib-slurm.sh,
# 2 CPUs) three ways: 1 task of 1 CPU at a time, 1 task of 2 CPUs at a time (the worker's
# OpenMP pool uses both), 2 concurrent tasks of 1 CPU each (--cpus N --max-running K).
# Prints the wall time of each batch from submission to its finish step, the ratios, and
# the 1-minute load average before and after each (the machine is shared).
# Usage: bench/slurm-scaling.sh BUILD_DIR [N_TILES]   (root; runs itself in `unshare -n`)
set -u
bin=$(cd "$1" && pwd) n=${2:-6}
src=$(cd "$(dirname "$0")/.." && pwd)
export PATH=$PATH:/usr/sbin
command -v slurmctld >/dev/null || { echo "skip: slurm-wlm not installed"; exit 77; }
if [ -z "${IMPASTO_SLURM_NETNS:-}" ]; then
  IMPASTO_SLURM_NETNS=1 exec unshare -n bash "$0" "$@"
fi
ip link set lo up && ip addr add 127.0.0.2/8 dev lo 2>/dev/null
tmp=$(mktemp -d /tmp/impasto-slurm-bench.XXXXXX)
scale=1
. "$src/tests/integration/lib-slurm.sh"
trap 'stop_all; rm -rf "$tmp"' EXIT
for i in $(seq 1 "$n"); do
  "$bin/cli/impasto" sim render --scene "$src/config/scenes/small.cfg" --plan "$src/config/plans/small.cfg" \
    --out "$tmp/sets/tile-$i" --seed "$i" --quiet --threads 2 >/dev/null 2>&1 || { echo "render failed"; exit 1; }
done
slurm_start "$tmp/slurm" || { echo "Slurm did not come up"; exit 1; }
load() { cut -d' ' -f1 /proc/loadavg; }
run() {   # run NAME CPUS MAX_RUNNING: prints seconds
  local t0 t1 batch
  t0=$(date +%s.%N)
  batch=$("$bin/cli/impasto" jobs submit --slurm --shared "$tmp/shared-$1" --cpus "$2" --max-running "$3" \
          --mem 512M --name "$1" "$tmp"/sets/tile-* | tail -1)
  while [ ! -e "$batch/result.json" ]; do
    squeue -h -n "impasto-finish-$(basename "$batch")" | grep -q . || [ -e "$batch/result.json" ] || \
      { echo "batch $1 ended without its result" >&2; "$bin/cli/impasto" jobs list --slurm "$batch" >&2; exit 1; }
    sleep 0.2
  done
  t1=$(date +%s.%N)
  echo "$t1 - $t0" | bc -l
}
# Three batches, back to back: 1 task of 1 CPU at a time (serial), 1 task of 2 CPUs at a
# time, 2 tasks of 1 CPU at a time. ORDER=reverse runs them in the opposite order.
confs=("serial 1 1" "one 2 1" "two 1 2")
[ "${ORDER:-}" = reverse ] && confs=("two 1 2" "one 2 1" "serial 1 1")
declare -A secs loads
for c in "${confs[@]}"; do
  set -- $c
  l0=$(load)
  secs[$1]=$(run "$1" "$2" "$3")
  loads[$1]="$l0 -> $(load)"
done
printf '%d tiles of small.cfg:\n' "$n"
printf '  1 task  x 1 CPU  at a time: %6.1f s (load %s)\n' "${secs[serial]}" "${loads[serial]}"
printf '  1 task  x 2 CPUs at a time: %6.1f s (load %s)\n' "${secs[one]}" "${loads[one]}"
printf '  2 tasks x 1 CPU  at a time: %6.1f s (load %s)\n' "${secs[two]}" "${loads[two]}"
printf '  speed-up of 2 concurrent tasks over 1: %.2f (over 1 task of 2 CPUs: %.2f)\n' \
  "$(echo "${secs[serial]} / ${secs[two]}" | bc -l)" "$(echo "${secs[one]} / ${secs[two]}" | bc -l)"
