# Sourced by the tests/integration/daemon-*.sh scripts: checks that count, JSON look-ups,
# and the emulated rig (`impasto sim serve`) with impastod in front of it, both stopped on
# exit. The caller sets build, src and port, then calls lib_init.
failures=0 checks=0
serve_pid="" daemon_pid=""
trap 'exit 143' TERM INT     # so that the EXIT trap (lib_cleanup) stops what was started

# lib_init NAME: the binaries (exit 77 when not built), a fresh $tmp, cleanup on exit.
lib_init() {
  imp=$build/cli/impasto
  [ -x "$imp" ] && [ -x "$build/daemon/impastod" ] || { echo "SKIP: $imp or $build/daemon/impastod not built"; exit 77; }
  tmp=$(mktemp -d "/tmp/impasto-$1.XXXXXX")
  trap lib_cleanup EXIT
}

lib_cleanup() {
  [ -z "$daemon_pid" ] || { kill -TERM "$daemon_pid" 2>/dev/null; wait "$daemon_pid" 2>/dev/null; }
  [ -z "$serve_pid" ] || { kill -TERM "$serve_pid" 2>/dev/null; wait "$serve_pid" 2>/dev/null; }
  if [ "$failures" -eq 0 ]; then rm -rf "$tmp"; else echo "kept $tmp"; fi
}

check() {   # check DESCRIPTION COMMAND...
  local what=$1; shift
  checks=$((checks + 1))
  if "$@"; then echo "ok: $what"; else echo "FAIL: $what"; failures=$((failures + 1)); fi
}

jget() {    # jget FILE PYTHON-EXPRESSION-ON-j
  python3 -c 'import json,sys; j=json.load(open(sys.argv[1])); print(eval(sys.argv[2]))' "$1" "$2"
}

# serve_start SCENE SEED: serves SCENE on 127.0.0.1 (GVCP) and Modbus $port, writes
# $tmp/rig.json and $tmp/rig.cfg (config/rigs/sim.cfg for it). Waits while another test
# holds the GVCP port; exits 77 when it stays busy.
serve_start() {
  local scene=$1 seed=$2 attempt
  for attempt in $(seq 15); do
    rm -f "$tmp/ready"
    "$build/cli/impasto" sim serve --scene "$scene" --address 127.0.0.1 --modbus-port "$port" --seed "$seed" \
      --rig-out "$tmp/rig.json" --ready-file "$tmp/ready" >"$tmp/serve.log" 2>&1 &
    serve_pid=$!
    for _ in $(seq 600); do
      [ -s "$tmp/ready" ] || ! kill -0 "$serve_pid" 2>/dev/null && break
      sleep 0.1
    done
    [ -s "$tmp/ready" ] && break
    kill -TERM "$serve_pid" 2>/dev/null; wait "$serve_pid" 2>/dev/null; serve_pid=""
    grep -q "in use" "$tmp/serve.log" || { cat "$tmp/serve.log"; echo "FAIL: impasto sim serve did not start"; exit 1; }
    sleep 2
  done
  [ -n "$serve_pid" ] || { echo "SKIP: the GVCP port or TCP $port stayed busy"; exit 77; }
  local proj
  proj=$(jget "$tmp/rig.json" 'j["projector"]["name"]')
  sed -e "s|127\.0\.0\.1:15020|127.0.0.1:$port|g" -e "s|calibration = \"rig.json\"|calibration = \"$tmp/rig.json\"|" \
      -e "s|name = \"proj0\"|name = \"$proj\"|" "$src/config/rigs/sim.cfg" >"$tmp/rig.cfg"
  grep -q "127.0.0.1:$port" "$tmp/rig.cfg" || { echo "FAIL: config/rigs/sim.cfg changed shape"; exit 1; }
}

# daemon_start EXTRA-OPTIONS...: impastod on $tmp/control.sock, state in $tmp/state, plans
# below $tmp/plans; returns once `status` answers.
daemon_start() {
  sock=$tmp/control.sock
  mkdir -p "$tmp/plans" "$tmp/state"
  "$build/daemon/impastod" --rig "$tmp/rig.cfg" --socket "$sock" --state-dir "$tmp/state" --operators-all \
    --plan-dir "$tmp/plans" --worker-cmd /bin/true --min-free-bytes 0 "$@" >>"$tmp/impastod.log" 2>&1 &
  daemon_pid=$!
  for _ in $(seq 100); do "$build/cli/impasto" status --socket "$sock" >/dev/null 2>&1 && return 0; sleep 0.1; done
  echo "FAIL: impastod did not answer"; cat "$tmp/impastod.log"; exit 1
}

# rig_stop: stops impastod and the served rig (before serving another scene).
rig_stop() {
  kill -TERM "$daemon_pid" "$serve_pid" 2>/dev/null
  wait "$daemon_pid" "$serve_pid" 2>/dev/null
  daemon_pid="" serve_pid=""
}

# capture_scene SCENE SEED PLAN NAME TIMEOUT_S: the board "moved" to SCENE: serves it, captures
# PLAN as an ordinary session NAME (impastod with --calibrate-cmd $imp, state kept in
# $tmp/state), stops both; checks that the session completed and leaves its id in $captured.
capture_scene() {
  serve_start "$1" "$2"
  daemon_start --calibrate-cmd "$imp" --retries 10
  "$imp" scan start "$3" --name "$4" --json --socket "$sock" >"$tmp/$4.json" 2>"$tmp/e"
  captured=$(jget "$tmp/$4.json" 'j["session"]')
  check "$4 captured ($(basename "$1"))" [ "$(session_wait "$captured" "$5")" = completed ]
  rig_stop
}

# A capture that paused on a device fault (a grab timing out while a loaded machine renders
# slowly) is resumed, as an operator would, up to 5 times per wait.
resume_if_paused() {   # resume_if_paused SESSION
  [ "$resumes" -lt 5 ] || return 0
  "$imp" scan show "$1" --json --socket "$sock" 2>/dev/null | grep -q '"state": *"paused"' || return 0
  resumes=$((resumes + 1))
  echo "note: session $1 paused on a fault; resuming ($resumes)" >&2
  "$imp" scan resume "$1" --socket "$sock" >/dev/null 2>&1
}

# session_wait SESSION TIMEOUT_S: prints the final state (completed, aborted, failed), paused
# when it stays paused after 5 resumes, or the last state seen at the timeout.
session_wait() {
  local end=$(( $(date +%s) + $2 )) st="" resumes=0
  while [ "$(date +%s)" -lt "$end" ]; do
    st=$("$imp" scan show "$1" --json --socket "$sock" 2>/dev/null | python3 -c 'import json,sys; print(json.load(sys.stdin)["state"])' 2>/dev/null)
    case "$st" in completed|aborted|failed) break;; paused) [ "$resumes" -lt 5 ] || break;; esac
    resume_if_paused "$1"
    sleep 1
  done
  echo "$st"
}

# calibrate_wait VERSION TIMEOUT_S: polls `calibrate show` until the calibration is done or
# failed, resuming its capture if it pauses; leaves the last answer in $tmp/show.json and
# prints the state.
calibrate_wait() {
  local end=$(( $(date +%s) + $2 )) st="" resumes=0
  while [ "$(date +%s)" -lt "$end" ]; do
    "$imp" calibrate show "$1" --json --socket "$sock" >"$tmp/show.json" 2>/dev/null
    st=$(jget "$tmp/show.json" 'j["state"]' 2>/dev/null)
    [ "$st" = done ] || [ "$st" = failed ] && break
    [ "$st" != capturing ] || resume_if_paused "$(jget "$tmp/show.json" 'j["session"]')"
    sleep 1
  done
  echo "$st"
}

lib_finish() {
  if [ -n "$daemon_pid" ]; then
    kill -TERM "$daemon_pid"; wait "$daemon_pid"; local rc=$?
    daemon_pid=""
    check "impastod stopped by SIGTERM with exit 0" [ $rc -eq 0 ]
  fi
  check "no sanitizer report in impastod's log" sh -c "! grep -q 'Sanitizer\|runtime error' '$tmp/impastod.log'"
  echo "$checks checks, $failures failed"
  [ "$failures" -eq 0 ] || { echo "--- impastod.log"; tail -40 "$tmp/impastod.log"; exit 1; }
  exit 0
}
