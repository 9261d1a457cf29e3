#!/bin/bash
# impasto-worker --capture, the unit a cluster engine schedules (docs/scale-out.md), without
# Slurm: a run SIGKILLed mid-run leaves no copy under COPY (only COPY.partial); the rerun
# starts from scratch and gives the reference copy byte for byte (copy.json without its
# timings, peak RSS and capture path); a rerun of the finished job is a no-op that leaves the
# copy untouched; other worker_args are other inputs (processed again); a lock held on
# COPY.lock refuses a second worker (exit 3).
# Usage: slurm-worker-oneshot.sh BUILD_DIR SOURCE_DIR
set -u
bin=$(cd "$1" && pwd) src=$(cd "$2" && pwd)
NAME=worker-oneshot
. "$src/tests/integration/lib-check.sh"
worker=$bin/cli/impasto-worker
"$imp" sim render --scene "$src/tests/data/worker-tiny.cfg" --plan "$src/tests/data/worker-tiny-plan.cfg" \
  --out "$tmp/set" --seed 4 --quiet --threads 2 >"$tmp/render.log" 2>&1 || { cat "$tmp/render.log"; echo "FAIL render"; exit 1; }
"$worker" --capture "$tmp/set" --copy "$tmp/ref" >"$tmp/ref.log" 2>&1 || { cat "$tmp/ref.log"; echo "FAIL reference"; exit 1; }

# killed mid-run: held before its last step (test-only IMPASTO_WORKER_TEST_HOLD), so that the
# kill lands while it runs whatever the load
mkdir -p "$tmp/hold"
IMPASTO_WORKER_TEST_HOLD=$tmp/hold "$worker" --capture "$tmp/set" --copy "$tmp/out/copy" >"$tmp/killed.log" 2>&1 &
pid=$!
for _ in $(seq $((900 * ${IMPASTO_TIMEOUT_SCALE:-1}))); do [ -s "$tmp/hold/copy.held" ] && break; sleep 0.1; done
check "the held marker names the worker" [ "$(cat "$tmp/hold/copy.held" 2>/dev/null)" = "$pid" ]
check "the kill came mid-run (the worker was alive)" kill -9 "$pid"
wait "$pid" 2>/dev/null
check "a killed run publishes no copy" [ ! -e "$tmp/out/copy" ]
check "a killed run leaves its work in COPY.partial" [ -d "$tmp/out/copy.partial" ]
touch "$tmp/out/copy.partial/stale-marker"
"$worker" --capture "$tmp/set" --copy "$tmp/out/copy" >"$tmp/rerun.log" 2>&1
check "the rerun exits 0" [ $? -eq 0 ]
check "the rerun started from scratch" [ ! -e "$tmp/out/copy/stale-marker" ] && [ ! -e "$tmp/out/copy.partial" ]
same_copy() {
  python3 - "$1" "$2" <<'PY'
import json, os, sys
a, b = sys.argv[1], sys.argv[2]
def files(d):
    return sorted(os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs if f != "result.json")
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if not k.startswith("seconds") and k not in ("peak_rss_kib", "capture")}
    return [strip(v) for v in x] if isinstance(x, list) else x
if files(a) != files(b):
    sys.exit("different files")
for f in files(a):
    pa, pb = os.path.join(a, f), os.path.join(b, f)
    same = strip(json.load(open(pa))) == strip(json.load(open(pb))) if f == "copy.json" else open(pa, "rb").read() == open(pb, "rb").read()
    if not same:
        sys.exit(f + " differs")
PY
}
check "the rerun's copy equals the reference" same_copy "$tmp/ref" "$tmp/out/copy"
check "result.json says done" grep -q '"state": "done"' "$tmp/out/copy/result.json"

# idempotent
before=$(stat -c %Y.%i "$tmp/out/copy/heightfield.exr" "$tmp/out/copy/result.json")
"$worker" --capture "$tmp/set" --copy "$tmp/out/copy" >"$tmp/again.log" 2>&1
check "a finished job reruns as a no-op" grep -q "nothing to do" "$tmp/again.log"
check "the no-op leaves the copy untouched" [ "$(stat -c %Y.%i "$tmp/out/copy/heightfield.exr" "$tmp/out/copy/result.json")" = "$before" ]
"$worker" --capture "$tmp/set" --copy "$tmp/out/copy" --args "--no-btf" >"$tmp/args.log" 2>&1
check "other worker_args are other inputs: processed again" bash -c "! grep -q 'nothing to do' $tmp/args.log && [ ! -e $tmp/out/copy/rho_d.exr ]"

# a second worker on the same copy
python3 -c 'import fcntl,sys,time; f=open(sys.argv[1],"w"); fcntl.flock(f,fcntl.LOCK_EX); open(sys.argv[2],"w").close(); time.sleep(30)' \
  "$tmp/out/locked.lock" "$tmp/locked" &
lpid=$!
for _ in $(seq 100); do [ -e "$tmp/locked" ] && break; sleep 0.1; done
"$worker" --capture "$tmp/set" --copy "$tmp/out/locked" >"$tmp/lock.log" 2>&1
rc=$?
kill "$lpid"; wait "$lpid" 2>/dev/null
check "a copy another worker is building is refused (exit 3)" [ $rc -eq 3 ]
check "... saying so" grep -q "another worker is building this copy" "$tmp/lock.log"
finish
