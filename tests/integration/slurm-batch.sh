#!/bin/bash
# Processing on a real Slurm (docs/scale-out.md): starts munged, slurmctld and slurmd on this
# machine in the foreground (generated slurm.conf, one node, 2 CPUs, state under $tmp) in a
# private network namespace, renders N_SETS small capture sets (tests/data/worker-tiny.cfg
# with seeds 1..N_SETS), processes them locally with impasto-worker --capture, then
# `impasto jobs submit --slurm` as one job array (%2) plus the dependent finish step. Task 1
# is killed (SIGKILL of its impasto-worker) mid-run: the task ends failed, its copy is not
# published (only COPY.partial exists), the finish step does not run. `impasto jobs retry
# --slurm` resubmits task 1 alone; afterwards every copy equals the local one byte for byte
# (every file; copy.json with its timings, peak RSS and capture path removed: those differ
# between any two runs, see docs/scale-out.md) and a rerun of a done task is a no-op.
# Exit 77 only when the Slurm or munge programs are not installed.
# Usage: slurm-batch.sh BUILD_DIR SOURCE_DIR [N_SETS]
set -u
bin=$(cd "$1" && pwd) src=$(cd "$2" && pwd) n_sets=${3:-3}
for p in munged mungekey slurmctld slurmd sbatch squeue scancel sinfo; do
  command -v "$p" >/dev/null || PATH=$PATH:/usr/sbin command -v "$p" >/dev/null ||
    { echo "skip: $p not installed (apt-get install slurm-wlm munge)"; exit 77; }
done
export PATH=$PATH:/usr/sbin
# Slurm's ports (6817, 6818) are the machine's: run in a private network namespace.
if [ -z "${IMPASTO_SLURM_NETNS:-}" ]; then
  command -v unshare >/dev/null || { echo "FAIL unshare not found"; exit 1; }
  IMPASTO_SLURM_NETNS=1 exec unshare -n bash "$0" "$@"
fi
ip link set lo up && ip addr add 127.0.0.2/8 dev lo 2>/dev/null
NAME=slurm
. "$src/tests/integration/lib-check.sh"
worker=$bin/cli/impasto-worker
. "$src/tests/integration/lib-slurm.sh"
scale=${IMPASTO_TIMEOUT_SCALE:-1}

trap 'stop_all; rm -rf "$tmp"' EXIT

# ---- the capture sets and their local copies ----------------------------------------------
for i in $(seq 1 "$n_sets"); do
  "$imp" sim render --scene "$src/tests/data/worker-tiny.cfg" --plan "$src/tests/data/worker-tiny-plan.cfg" \
    --out "$tmp/sets/tile-$i" --seed "$i" --quiet --threads 2 >"$tmp/render.log" 2>&1 ||
    { cat "$tmp/render.log"; echo "FAIL sim render"; exit 1; }
  rm -rf "$tmp/sets/tile-$i/truth"
  "$worker" --capture "$tmp/sets/tile-$i" --copy "$tmp/local/tile-$i" >"$tmp/local.log" 2>&1 ||
    { cat "$tmp/local.log"; echo "FAIL local processing"; exit 1; }
done

# ---- a one-node Slurm ------------------------------------------------------------------------
slurm_start "$tmp/slurm" || { echo "FAIL the one-node Slurm did not come up"; exit 1; }
echo "ok   Slurm up: $(sinfo -h -N -o '%N %c CPUs %t')"

# ---- submit, kill task 1 mid-run --------------------------------------------------------------
# Every task, once processed and before its last step (result manifest, publishing the copy),
# writes $hold/<copy name>.held with its pid and waits for $hold/release (a test-only knob of
# impasto-worker): task 1 (copy tile-2) is killed while it certainly runs, then the others
# are released.
hold=$tmp/hold
mkdir -p "$hold"
export IMPASTO_WORKER_TEST_HOLD=$hold
"$imp" jobs submit --slurm --shared "$tmp/shared" --cpus 1 --mem 256M --max-running 2 --name tiles \
  "$tmp"/sets/tile-* >"$tmp/submit.out" 2>&1
rc=$?
cat "$tmp/submit.out"
check "jobs submit --slurm exits 0" [ $rc -eq 0 ]
batch=$(tail -1 "$tmp/submit.out")
[ -f "$batch/batch.json" ] || { echo "FAIL no batch directory"; exit 1; }
check "the array and the finish step are in Slurm's queue" \
  bash -c "[ \$(squeue -h -r -t all -o %i | wc -l) -eq $((n_sets + 1)) ]"

slurm_wait_for "task 1 held before its last step" 180 test -s "$hold/tile-2.held" || { squeue -t all; cat "$batch"/logs/*.out; exit 1; }
pid=$(cat "$hold/tile-2.held")
check "task 1's state file names the held worker" \
  [ "$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["pid"])' "$batch/tasks/1.json")" = "$pid" ]
check "task 1 (impasto-worker pid $pid) is running when killed" kill -9 "$pid"
echo "ok   killed task 1 after: $(grep '^task 1: ' "$batch/logs/task-1.out" | tail -1)"
touch "$hold/release"
batch_idle() { ! squeue -h -t pending,running,completing,configuring -n "impasto-tile-$(basename "$batch"),impasto-finish-$(basename "$batch")" | grep -q .; }
slurm_wait_for "the batch to stop" 120 batch_idle || { squeue -t all; exit 1; }
"$imp" jobs list --slurm "$batch" --json >"$tmp/status1.json"
"$imp" jobs list --slurm "$batch"
st() { python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); t=sys.argv[2]; print((d["finish"] if t=="finish" else d["tasks"][int(t)])["state"])' "$@"; }
check "task 1 is failed after the kill" [ "$(st "$tmp/status1.json" 1)" = failed ]
check "its error says it stopped while running" grep -q "stopped while running" "$tmp/status1.json"
check "task 0 is done" [ "$(st "$tmp/status1.json" 0)" = done ]
check "the finish step did not complete" [ "$(st "$tmp/status1.json" finish)" = failed ]
copies=$tmp/shared/copies/$(basename "$batch")
check "the killed task published no copy" [ ! -e "$copies/tile-2" ]
check "the killed task's partial copy is kept apart" [ -d "$copies/tile-2.partial" ]
check "no batch result after a failed task" [ ! -e "$batch/result.json" ]

# ---- retry ---------------------------------------------------------------------------------------
unset IMPASTO_WORKER_TEST_HOLD
"$imp" jobs retry --slurm "$batch" >"$tmp/retry.out" 2>&1
rc=$?
cat "$tmp/retry.out"
check "jobs retry --slurm resubmits the one failed task" grep -q "1 failed tasks resubmitted" "$tmp/retry.out"
slurm_wait_for "the retried batch to end" 120 batch_idle || { squeue -t all; exit 1; }
"$imp" jobs list --slurm "$batch" --json >"$tmp/status2.json"
"$imp" jobs list --slurm "$batch"
for i in $(seq 0 $((n_sets - 1))); do
  check "task $i done after the retry" [ "$(st "$tmp/status2.json" "$i")" = done ]
done
check "the finish step is done" [ "$(st "$tmp/status2.json" finish)" = done ]
check "the batch result says done" grep -q '"state": "done"' "$batch/result.json"
check "the finish step found nothing to mosaic (sets of no painting)" \
  grep -q '"reason": "nothing to mosaic: the captures are not the tiles of a painting' "$batch/result.json"
check "no partial copy is left" bash -c "! ls -d $copies/*.partial 2>/dev/null | grep -q ."

for i in $(seq 1 "$n_sets"); do
  check "tile-$i: the Slurm copy equals the local one" slurm_same_copy "$tmp/local/tile-$i" "$copies/tile-$i"
done
check "the two local runs differ only where stated (sanity of the comparison)" \
  bash -c "[ -n \"\$(cmp $tmp/local/tile-1/heightfield.exr $tmp/local/tile-2/heightfield.exr)\" ]"

# ---- idempotence ---------------------------------------------------------------------------------
before=$(stat -c %Y.%i "$copies/tile-1/heightfield.exr")
"$worker" --batch "$batch" --task 0 >"$tmp/rerun.out" 2>&1
check "a rerun of a done task exits 0" [ $? -eq 0 ]
check "a rerun of a done task says there is nothing to do" grep -q "nothing to do" "$tmp/rerun.out"
check "a rerun of a done task leaves the copy untouched" [ "$(stat -c %Y.%i "$copies/tile-1/heightfield.exr")" = "$before" ]

# ---- through impastod: scheduler = "slurm" ------------------------------------------------------
# Two jobs dropped into the daemon's queue (as an operator's tool would) go to Slurm as one
# array; task 1 is killed mid-run and the daemon resubmits it on its own (attempts left);
# `impasto jobs` shows both done like local jobs, and their copies equal the local ones.
if [ -x "$bin/daemon/impastod" ]; then
  st_dir=$tmp/state
  mkdir -p "$st_dir/jobs" "$st_dir/outputs"
  sed -e "s|calibration = \"rig.json\"|calibration = \"$tmp/sets/tile-1/rig.json\"|" "$src/config/rigs/sim.cfg" >"$tmp/rig.cfg"
  # the worker held before its last step through a wrapper (it execs: the pid stays the worker's)
  dhold=$tmp/hold-daemon
  mkdir -p "$dhold"
  printf '#!/bin/sh\nIMPASTO_WORKER_TEST_HOLD="%s" exec "%s" "$@"\n' "$dhold" "$worker" >"$tmp/slow-worker"
  chmod +x "$tmp/slow-worker"
  printf 'scheduler = "slurm";\nslurm = { shared_dir = "%s"; cpus_per_task = 1; mem = "256M"; max_running = 2; worker = "%s"; };\n' \
    "$tmp/shared" "$tmp/slow-worker" >"$tmp/scheduler.conf"
  "$bin/daemon/impastod" --rig "$tmp/rig.cfg" --socket "$tmp/control.sock" \
    --state-dir "$st_dir" --operators-all --worker-cmd "$worker" --min-free-bytes 0 \
    --scheduler-config "$tmp/scheduler.conf" >"$tmp/impastod.log" 2>&1 &
  pids+=($!)
  for _ in $(seq 100); do "$imp" status --socket "$tmp/control.sock" >/dev/null 2>&1 && break; sleep 0.1; done
  for i in 1 2; do
    printf '{"id":"d%s","capture":"%s","copy":"%s","state":"queued","attempts":0,"max_attempts":3,"error":null}\n' \
      "$i" "$tmp/sets/tile-$i" "$st_dir/outputs/tile-$i" >"$tmp/d$i.json"
  done
  mv "$tmp/d1.json" "$st_dir/jobs/d1.json"; mv "$tmp/d2.json" "$st_dir/jobs/d2.json"
  dslurm() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1])).get("slurm",{}).get(sys.argv[2],""))' "$st_dir/jobs/d2.json" "$1" 2>/dev/null; }
  d_held() { [ -s "$dhold/tile-2.held" ] && [ -n "$(dslurm batch)" ] && [ -n "$(dslurm task)" ]; }
  slurm_wait_for "the daemon's job d2 held before its last step" 180 d_held || { cat "$tmp/impastod.log"; squeue -t all; exit 1; }
  b=$(dslurm batch) t=$(dslurm task)
  echo "daemon job d2 is task $t of $b: $(cat "$b/tasks/$t.json" | tr -d '\n '); log: $(tr '\n' '|' <"$b/logs/task-$t.out")"
  check "the daemon's job d2 is running when killed" kill -9 "$(cat "$dhold/tile-2.held")"
  touch "$dhold/release"
  both_done() { [ "$("$imp" jobs --socket "$tmp/control.sock" 2>/dev/null | grep -c ' done ')" -eq 2 ]; }
  slurm_wait_for "both daemon jobs done" 150 both_done
  "$imp" jobs --socket "$tmp/control.sock"
  check "impasto jobs shows both Slurm jobs done" both_done
  "$imp" jobs show d2 --json --socket "$tmp/control.sock" >"$tmp/d2.json"
  check "the killed job took a second attempt" \
    [ "$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["attempts"])' "$tmp/d2.json")" = 2 ]
  check "the daemon resubmitted the killed task" grep -q "resubmitting, attempt 2" "$tmp/impastod.log" ||
    { cat "$tmp/impastod.log"; cat "$b"/logs/*.out; }
  for i in 1 2; do
    check "daemon job d$i: its copy equals the local one" slurm_same_copy "$tmp/local/tile-$i" "$st_dir/outputs/tile-$i"
  done
fi

stop_all
finish
