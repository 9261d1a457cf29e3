# night.sh, sourced by install-test.sh after its checks (root, prefix, conf, bin, tmp, check,
# failures, serve_pid, daemon_pid are its): the operator's night on the installed impastod
# with the installed config, against the emulated rig. Two paintings queued; the dome refuses
# a request in the first (an injected device fault: with retries = 1 the session pauses),
# impastod is SIGKILLed and restarted while it waits (the queue and the pause survive);
# `impasto status` names the paused session and the command to act on it, which the test
# then runs (scan resume --follow); the second painting's job fails (a worker wrapper
# refuses it). Then `impasto status` and `impasto report` must show the fault and the failed
# job with the command to act on each, session.log must carry the fault with a timestamp,
# and the hook must have received a fault, both sessions' ends and both jobs' ends.
cli=$root$prefix/bin/impasto
plans=$root$(sed -n 's/^ *plan_dirs *= *\[ *"\([^"]*\)".*/\1/p' "$root$conf")
nsock=$tmp/night.sock
wait_for() {    # wait_for SECONDS COMMAND...: until COMMAND succeeds, SECONDS of wall clock
  _wf_end=$(($(date +%s) + $1)); shift    # (not a count of tries: each try may take long)
  while :; do
    "$@" 2>/dev/null && return 0
    [ "$(date +%s)" -lt "$_wf_end" ] || return 1
    sleep 0.1
  done
}
status_json() { "$cli" status --socket "$nsock" --json >"$tmp/st.json" 2>/dev/null; }
jq_py() {       # jq_py FILE EXPR: a python expression over the JSON in FILE as j
  python3 -c 'import json,sys; j=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$@"
}
start_night_daemon() {
  "$root$bin" --config "$tmp/night.conf" --socket "$nsock" --operators-all >>"$tmp/night.log" 2>&1 &
  daemon_pid=$!
  wait_for 15 status_json
}

# the rig again, now with a dome that refuses its 20th Modbus request (mid first session)
kill -TERM $serve_pid; wait $serve_pid 2>/dev/null
rm -f "$tmp/ready"
"$cli" sim serve --scene "$src/config/scenes/small.cfg" --address 127.0.0.1 --fault modbus-exception=20 \
  --rig-out "$root$cfgdir/rig.json" --ready-file "$tmp/ready" >"$tmp/serve2.log" 2>&1 &
serve_pid=$!
wait_for 60 test -s "$tmp/ready" || { cat "$tmp/serve2.log"; echo "FAIL: sim serve with a fault"; exit 1; }

mkdir -p "$tmp/hooks" "$tmp/night-state"
cat >"$tmp/hook.sh" <<HOOK
#!/bin/sh
cat >"$tmp/hooks/\$(date +%s%N)-\$1.json"
HOOK
cat >"$tmp/worker.sh" <<WORKER
#!/bin/sh
# the job of the painting named "bad" fails (an injected failure); the installed worker otherwise
if grep -q '"session" *: *"[^"]*-bad"' "\$1"; then echo "injected failure: no copy for this painting" >&2; exit 3; fi
exec "$root$prefix/bin/impasto-worker" "\$@"
WORKER
chmod +x "$tmp/hook.sh" "$tmp/worker.sh"
sed -e 's|"'"$tmp/state"'|"'"$tmp/night-state"'|g' -e 's|^ *worker = .*|  worker = "'"$tmp/worker.sh"'";|' \
    -e 's|^ *# hook = .*|  hook = "'"$tmp/hook.sh"'";|' -e 's|^ *retries = .*|  retries = 1;|' \
    -e 's|^ *job_attempts = .*|  job_attempts = 1;|' -e 's|^ *# worker_args = .*|  worker_args = "--no-btf";|' \
    -e 's|^ *disk_low_mib = .*|  disk_low_mib = 1;|' "$tmp/impastod.conf" >"$tmp/night.conf"
check "night: the installed config with a hook and a worker wrapper starts impastod" start_night_daemon

"$cli" queue add "$plans/quick.cfg" --name good --socket "$nsock" >"$tmp/q1.txt" 2>&1
"$cli" queue add "$plans/quick.cfg" --name bad --socket "$nsock" >"$tmp/q2.txt" 2>&1
check "night: two paintings queued" grep -q "queued q2 at position" "$tmp/q2.txt"

# the first painting pauses with the camera's fault; the second waits for it
paused() { status_json && jq_py "$tmp/st.json" '[i["id"] for i in j["attention"]["items"] if i["kind"]=="session_paused"][0]' >"$tmp/paused.txt"; }
check "night: the dome fault pauses the first session" wait_for 120 paused
sid=$(cat "$tmp/paused.txt" 2>/dev/null)
"$cli" queue list --socket "$nsock" >"$tmp/qlist.txt" 2>&1
check "night: the second painting waits in the queue for the paused session" \
  grep -q "waiting: session $sid is paused" "$tmp/qlist.txt"

# SIGKILL while the night waits: the queue and the paused session survive the restart
kill -KILL $daemon_pid; wait $daemon_pid 2>/dev/null
check "night: impastod restarts after a SIGKILL" start_night_daemon
"$cli" queue list --socket "$nsock" >"$tmp/qlist2.txt" 2>&1
check "night: the queue survived the SIGKILL" grep -q "bad" "$tmp/qlist2.txt"
"$cli" status --socket "$nsock" >"$tmp/status1.txt" 2>&1
check "night: impasto status names the paused session and the command to resume it" \
  grep -q -- "-> impasto scan resume $sid --follow" "$tmp/status1.txt"
check "night: impasto status says DEGRADED" grep -q "DEGRADED" "$tmp/status1.txt"

# the operator does what status says
# (a GigE camera refuses a new controller until the killed one's heartbeat times out: an
# operator who resumes too early sees the session pause again and resumes once more)
for _ in 1 2 3; do
  sleep 4
  "$cli" scan resume "$sid" --follow --socket "$nsock" >"$tmp/follow.txt" 2>&1 && break
  check "night: a follow that ends in a pause says how to continue" \
    grep -q "continue with: impasto scan resume $sid --follow" "$tmp/follow.txt"
done
check "night: scan resume --follow follows the session to its end" grep -q "session $sid completed" "$tmp/follow.txt"
check "night: --follow prints one event per line (no carriage returns)" sh -c '! grep -q "$(printf "\r")" "$0"' "$tmp/follow.txt"

# the queue goes on: the second painting, then both jobs end (the second one failed)
jobs_ended() {
  "$cli" jobs list --socket "$nsock" --json >"$tmp/jobs.json" 2>/dev/null &&
  [ "$(jq_py "$tmp/jobs.json" 'sorted(x["state"] for x in j["jobs"])')" = "['done', 'failed']" ]
}
check "night: the second painting ran from the queue and both jobs ended (one done, one failed)" wait_for 240 jobs_ended
bad_job=$(jq_py "$tmp/jobs.json" '[x["job"] for x in j["jobs"] if x["state"]=="failed"][0]' 2>/dev/null)
"$cli" status --socket "$nsock" >"$tmp/status2.txt" 2>&1
check "night: impasto status shows the failed job with the command to retry it" \
  grep -q -- "-> impasto jobs retry $bad_job" "$tmp/status2.txt"
"$cli" report --since 1h --socket "$nsock" >"$tmp/report.txt" 2>&1
"$cli" report --since 1h --socket "$nsock" --json >"$tmp/report.json" 2>&1
check "night: impasto report lists the fault with its time" grep -Eq "^ +20[0-9-]+T[0-9:]+Z fault on " "$tmp/report.txt"
check "night: impasto report shows the failed job and the command to retry it" \
  grep -q -- "-> impasto jobs retry $bad_job" "$tmp/report.txt"
check "night: impasto report counts 2 sessions, 1 job done, 1 failed, 1 copy" \
  test "$(jq_py "$tmp/report.json" '[j["totals"][k] for k in ("sessions","jobs_done","jobs_failed","copies")]')" = "[2, 1, 1, 1]"
check "night: session.log carries the fault with a timestamp" \
  grep -Eq "^20[0-9-]+T[0-9:]+Z fault on " "$tmp/night-state/sessions/$sid/session.log"
check "night: session.log says the session came from the queue" \
  grep -q "started from the scan queue" "$tmp/night-state/sessions/$sid/session.log"
for ev in fault done; do
  check "night: the hook received a $ev event" sh -c 'ls "$0"/*-'"$ev"'.json >/dev/null 2>&1' "$tmp/hooks"
done
check "night: the hook received both sessions' ends" test "$(cat "$tmp"/hooks/*-done.json | grep -c '"state":"completed"')" -ge 2
check "night: the hook received the failed job with its error" grep -lq '"state":"failed"' "$tmp"/hooks/*-job.json
check "night: the hook received the done job" grep -lq '"state":"done"' "$tmp"/hooks/*-job.json
kill -TERM $daemon_pid; wait $daemon_pid; rc=$?; daemon_pid=""
check "night: impastod stops with exit 0" [ $rc -eq 0 ]
[ $failures -eq 0 ] || { echo "--- night.log"; cat "$tmp/night.log"; ls -l "$tmp/hooks"; cat "$tmp/status2.txt" "$tmp/report.txt"; }
