#!/bin/bash
# A whole painting through Slurm gives the same copy as local processing (docs/scale-out.md):
# renders a painting of COLS x ROWS tiles (tests/data/worker-painting.cfg, the plan's extent
# widened; 5 x 4 = 20 tiles by default), processes every tile locally (impasto-worker
# --capture, the processing of the local queue) and mosaics them (impasto mosaic), then
# submits the tiles with `impasto jobs submit --slurm` to a one-node Slurm (lib-slurm.sh) and
# checks that every tile copy equals the local one (every file byte for byte; copy.json
# without timings, peak RSS and capture path) and that the finish step's mosaic equals the
# local mosaic (every file byte for byte; mosaic.json without the tile copies' paths). Exit 77 only when the Slurm or munge programs are missing.
# Usage: slurm-painting.sh BUILD_DIR SOURCE_DIR [EXTENT_W_MM EXTENT_H_MM]  (126 74: 5 x 4 tiles)
set -u
bin=$(cd "$1" && pwd) src=$(cd "$2" && pwd) ew=${3:-126.0} eh=${4:-74.0}
for p in munged mungekey slurmctld slurmd sbatch squeue scancel sinfo; do
  command -v "$p" >/dev/null || PATH=$PATH:/usr/sbin command -v "$p" >/dev/null ||
    { echo "skip: $p not installed (apt-get install slurm-wlm munge)"; exit 77; }
done
export PATH=$PATH:/usr/sbin
if [ -z "${IMPASTO_SLURM_NETNS:-}" ]; then
  command -v unshare >/dev/null || { echo "FAIL unshare not found"; exit 1; }
  IMPASTO_SLURM_NETNS=1 exec unshare -n bash "$0" "$@"
fi
ip link set lo up && ip addr add 127.0.0.2/8 dev lo 2>/dev/null
NAME=slurm-painting
. "$src/tests/integration/lib-check.sh"
worker=$bin/cli/impasto-worker
. "$src/tests/integration/lib-slurm.sh"
scale=${IMPASTO_TIMEOUT_SCALE:-1}
trap 'stop_all; rm -rf "$tmp"' EXIT
t0=$(date +%s)

# ---- the painting, processed locally ----------------------------------------------------------
sed "s/extent_mm = \[52.0, 22.0\];/extent_mm = [$ew, $eh];/" "$src/tests/data/worker-painting-plan.cfg" >"$tmp/plan.cfg"
P=$tmp/painting
"$imp" sim render --scene "$src/tests/data/worker-painting.cfg" --plan "$tmp/plan.cfg" --out "$P" --quiet \
  --threads 2 >"$tmp/render.log" 2>&1 || { cat "$tmp/render.log"; echo "FAIL sim render"; exit 1; }
tiles=$(ls "$P/tiles")
n=$(echo "$tiles" | wc -l)
echo "ok   rendered $n tiles ($(($(date +%s) - t0)) s)"
# one pitch for every tile (the mosaic wants one per painting)
args="--pitch 0.2"
for t in $tiles; do
  "$worker" --capture "$P/tiles/$t" --copy "$P/copies/$t" --args "$args" >"$tmp/local.log" 2>&1 ||
    { cat "$tmp/local.log"; echo "FAIL local processing of tile $t"; exit 1; }
done
"$imp" mosaic "$P" --out "$tmp/local-mosaic" >"$tmp/local-mosaic.log" 2>&1 ||
  { cat "$tmp/local-mosaic.log"; echo "FAIL local mosaic"; exit 1; }
echo "ok   processed and mosaicked locally ($(($(date +%s) - t0)) s)"

# ---- the same through Slurm -------------------------------------------------------------------
slurm_start "$tmp/slurm" || { echo "FAIL the one-node Slurm did not come up"; exit 1; }
"$imp" jobs submit --slurm --shared "$tmp/shared" --cpus 1 --mem 256M --max-running 2 --name painting \
  --worker-args "$args" $(for t in $tiles; do echo "$P/tiles/$t"; done) >"$tmp/submit.out" 2>&1
check "jobs submit --slurm of $n tiles exits 0" [ $? -eq 0 ] || { cat "$tmp/submit.out"; exit 1; }
batch=$(tail -1 "$tmp/submit.out")
batch_idle() { ! squeue -h -t pending,running,completing,configuring -n "impasto-tile-$(basename "$batch"),impasto-finish-$(basename "$batch")" | grep -q .; }
slurm_wait_for "the batch to end" $((60 + 30 * n)) batch_idle || { squeue -t all; exit 1; }
echo "ok   the batch ended ($(($(date +%s) - t0)) s)"
"$imp" jobs list --slurm "$batch"
copies=$tmp/shared/copies/$(basename "$batch")
same=0
for t in $tiles; do slurm_same_copy "$P/copies/$t" "$copies/$t" && same=$((same + 1)); done
check "every tile copy through Slurm equals the local one ($same of $n)" [ $same -eq "$n" ]
mfield() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["mosaic"].get(sys.argv[2], ""))' "$batch/result.json" "$1"; }
check "the finish step mosaicked the $n tiles" [ "$(mfield state)/$(mfield tiles)" = "done/$n" ]
check "the Slurm mosaic equals the local one (every file; mosaic.json but for the copies' paths)" \
  slurm_same_mosaic "$tmp/local-mosaic" "$batch/mosaic"
echo "($(($(date +%s) - t0)) s in all)"
finish
