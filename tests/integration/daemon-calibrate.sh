#!/bin/bash
# impastod's `calibrate` end to end on the emulated rig (issues #7, #8): `impasto sim serve`
# serves a noisy flat white target; `impasto calibrate start radiometric --follow` makes the
# daemon capture the photon-transfer plan (from its --plan-dir) as a session, run
# `impasto calibrate radiometric` on the set as its own durable job and store the result as
# calibration version 1, which is then in force: the next scan's set names version 1 and
# carries the calibrated sensor; `calibrate start projector-gamma` then estimates the
# projector's gamma and black level on top of it (version 3, keeping version 2's sensor). The daemon is SIGKILLed while the routine runs and restarted:
# the routine runs again (attempt 2) and the calibration still ends done. Also: routine
# parameters checked (args.args.KEY; the lights routine's detection parameters and earlier
# sessions at board heights, "ID@Z", each refused naming the field; valid ones reach the
# routine as --set SET@Z), and plan paths confined to the plan directories
# (/etc/passwd, a symlink out of the plan directory, a directory, a file the client itself
# cannot read), each refused naming the path.
# Usage: daemon-calibrate.sh BUILD_DIR SOURCE_DIR MODBUS_PORT
set -u
build=$1 src=$2 port=$3
. "$src/tests/integration/lib-daemon.sh"
lib_init calibrate
chmod 755 "$tmp"

# ---- the emulated rig: flat-white with the noise and projector effects (the projector-gamma
# routine needs its light), the sensor of config/scenes/flat-white.cfg
sed 's/effects = \["direct"\];/effects = ["direct", "noise", "projector"];/' "$src/config/scenes/flat-white.cfg" >"$tmp/flat-noise.cfg"
grep -q '"noise"' "$tmp/flat-noise.cfg" || { echo "FAIL: flat-white.cfg changed shape"; exit 1; }
serve_start "$tmp/flat-noise.cfg" 3
mkdir -p "$tmp/plans"
cp "$src/config/plans/photon-transfer.cfg" "$src/config/plans/projector-gamma.cfg" "$tmp/plans/"
printf 'dome = { lights = [0, 1]; exposures_us = [2000.0]; };\n' >"$tmp/plans/sweep.cfg"
# a wrapper around the offline routines: waits on its first run so that the daemon can be
# killed while the routine runs
cat >"$tmp/calibrate-cmd" <<EOF
#!/bin/sh
echo run >>"$tmp/routine-runs"
[ "\$(wc -l <"$tmp/routine-runs")" -gt 1 ] || sleep 5
exec "$imp" "\$@"
EOF
chmod +x "$tmp/calibrate-cmd"
start_daemon() { daemon_start --calibrate-cmd "$tmp/calibrate-cmd"; }
start_daemon

# ---- routine parameters and the plan's confinement
"$imp" calibrate start radiometric --arg lens=5 --socket "$sock" >"$tmp/o" 2>"$tmp/e"; rc=$?
check "unknown routine parameter: exit 3" [ $rc -eq 3 ]
check "unknown routine parameter named" grep -q "args.args.lens" "$tmp/e"
"$imp" calibrate start lights --socket "$sock" >"$tmp/o" 2>"$tmp/e"; rc=$?
check "lights with neither sphere_radius nor spheres: exit 3 naming args.args.sphere_radius" \
  sh -c "[ $rc -eq 3 ] && grep -q 'args.args.sphere_radius' '$tmp/e'"
"$imp" calibrate start lights --arg sphere_radius=10 --arg hemispheres --arg sphere_cut=7 --socket "$sock" \
  >"$tmp/o" 2>"$tmp/e"; rc=$?
check "the client passes --arg hemispheres as true (refused with sphere_cut, naming it)" \
  sh -c "[ $rc -eq 3 ] && grep -q 'together with hemispheres.*(args.args.sphere_cut)' '$tmp/e'"
"$imp" calibrate start lights --arg sphere_radius=10 --arg 'sessions=["nosuch@20"]' --socket "$sock" \
  >"$tmp/o" 2>"$tmp/e"; rc=$?
check "the client passes sessions as a list (an unknown one refused, naming it)" \
  sh -c "[ $rc -eq 3 ] && grep -q 'nosuch is not a completed session.*(args.args.sessions\[0\])' '$tmp/e'"
"$imp" scan start /etc/passwd --socket "$sock" >"$tmp/o" 2>"$tmp/e"; rc=$?
check "/etc/passwd refused (exit 3), naming it and the plan directories" \
  sh -c "[ $rc -eq 3 ] && grep -q '/etc/passwd: not a plan of this daemon' '$tmp/e' && grep -q '$tmp/plans' '$tmp/e'"
check "nothing of /etc/passwd in the error" sh -c "! grep -q 'root:' '$tmp/e'"
ln -s /etc/passwd "$tmp/plans/link.cfg"
# raw, so that no client resolves the link first
python3 - "$sock" "$tmp/plans/link.cfg" >"$tmp/raw.json" <<'PY'
import json, socket, sys
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); f = s.makefile("rw")
f.readline()
f.write(json.dumps({"id": 1, "cmd": "plan.validate", "args": {"plan": sys.argv[2]}}) + "\n"); f.flush()
print(f.readline())
PY
check "a symlink out of the plan directory refused as not_found, naming the link" \
  sh -c "grep -q '\"not_found\"' '$tmp/raw.json' && grep -q 'link.cfg: not a plan of this daemon' '$tmp/raw.json'"
mkdir "$tmp/plans/dir.cfg"
"$imp" scan start "$tmp/plans/dir.cfg" --socket "$sock" >"$tmp/o" 2>"$tmp/e"; rc=$?
check "a directory refused" sh -c "[ $rc -eq 3 ] && grep -q 'dir.cfg: not a regular file' '$tmp/e'"
cp "$tmp/plans/sweep.cfg" "$tmp/plans/secret.cfg"
chmod 600 "$tmp/plans/secret.cfg"
chmod 755 "$tmp/plans"
chmod 666 "$sock"
if setpriv --reuid=65534 --regid=65534 --clear-groups true 2>/dev/null; then
  setpriv --reuid=65534 --regid=65534 --clear-groups "$imp" scan start "$tmp/plans/secret.cfg" --socket "$sock" \
    >"$tmp/o" 2>"$tmp/e"; rc=$?
  check "a plan the client cannot read is not read for it" \
    sh -c "[ $rc -eq 3 ] && grep -q 'secret.cfg: not readable by the client (uid 65534)' '$tmp/e'"
  setpriv --reuid=65534 --regid=65534 --clear-groups "$imp" plan validate "$tmp/plans/sweep.cfg" --daemon --socket "$sock" \
    >"$tmp/o" 2>"$tmp/e"; rc=$?
  check "a plan the client can read is validated for it" [ $rc -eq 0 ]
else
  echo "note: setpriv cannot drop to uid 65534 here; the peer-rights check is not exercised"
fi

# ---- the calibration: capture, routine (killed once), result in force
"$imp" calibrate start radiometric --socket "$sock" --json >"$tmp/start.json" 2>"$tmp/e"; rc=$?
check "calibrate start radiometric: exit 0" [ $rc -eq 0 ]
cal=$(jget "$tmp/start.json" 'j["calibration"]')
session=$(jget "$tmp/start.json" 'j["session"]')
check "the first calibration is version 1" [ "$cal" = 1 ]
check "the default plan came from the plan directory" grep -q "$tmp/plans/photon-transfer.cfg" "$tmp/start.json"
# wait for the routine to start (the wrapper's first run sleeps), then kill the daemon
for _ in $(seq 300); do [ -s "$tmp/routine-runs" ] && break; sleep 0.1; done
check "the routine started after the capture" [ -s "$tmp/routine-runs" ]
check "the calibration job says running" \
  sh -c "grep -q '\"state\": *\"running\"' '$tmp/state/calibrations/1/calibration.json'"
kill -KILL "$daemon_pid"; wait "$daemon_pid" 2>/dev/null; daemon_pid=""
sleep 0.5
start_daemon
"$imp" calibrate show 1 --socket "$sock" --json >"$tmp/show.json" 2>/dev/null
for _ in $(seq 600); do
  "$imp" calibrate show 1 --socket "$sock" --json >"$tmp/show.json" 2>/dev/null
  st=$(jget "$tmp/show.json" 'j["state"]' 2>/dev/null)
  [ "$st" = done ] || [ "$st" = failed ] && break
  sleep 0.1
done
check "after SIGKILL and restart the calibration ends done" [ "$st" = done ]
check "it took a second attempt" [ "$(jget "$tmp/show.json" 'j["attempts"]')" = 2 ]
check "the routine ran twice" [ "$(wc -l <"$tmp/routine-runs")" -eq 2 ]
check "its session is the calibration's" [ "$(jget "$tmp/show.json" 'j["session"]')" = "$session" ]
check "rig.json and report.json stored" \
  test -s "$tmp/state/calibrations/1/rig.json" -a -s "$tmp/state/calibrations/1/report.json"
check "it is the calibration in force" [ "$(jget "$tmp/show.json" 'j["current"]')" = True ]
gain=$(jget "$tmp/show.json" 'j["figures"]["sensor.gain_e_per_dn"]')
rn=$(jget "$tmp/show.json" 'j["figures"]["sensor.read_noise_e"]')
black=$(jget "$tmp/show.json" 'j["figures"]["sensor.black_level_dn"]')
echo "daemon photon transfer: gain $gain e/DN (true 2.5), read noise $rn e (true 3.0), black $black DN (true 64)"
check "gain within 3 % of the emulated sensor's 2.5 e/DN" python3 -c "import sys; sys.exit(abs($gain/2.5-1) > 0.03)"
check "read noise within 10 % of 3.0 e" python3 -c "import sys; sys.exit(abs($rn/3.0-1) > 0.10)"
check "black level within 0.5 DN of 64" python3 -c "import sys; sys.exit(abs($black-64) > 0.5)"
check "the capture set was not queued for processing" [ ! -e "$tmp/state/jobs/$session.json" ]
"$imp" status --socket "$sock" --json >"$tmp/status.json"
check "status names calibration 1" [ "$(jget "$tmp/status.json" 'j["rig"]["calibration"]')" = 1 ]
"$imp" calibrate list --socket "$sock" --json >"$tmp/list.json"
check "calibrate list: version 1 in force" [ "$(jget "$tmp/list.json" 'j["current"]["version"]')" = 1 ]

# ---- bad lights parameters, each refused with an error object naming the field (raw, so that
# the error object itself is seen); $session is a completed session of this daemon. Valid ones
# get past the parameters to the plan (none for lights here: not_found args.plan).
python3 - "$sock" "$session" >"$tmp/lights-args.json" <<'PY'
import json, socket, sys
s = socket.socket(socket.AF_UNIX); s.connect(sys.argv[1]); f = s.makefile("rw")
f.readline()
done = sys.argv[2]
cases = [{}, {"spheres": "13,12,9,0;47,12,9,0", "sphere_radius": 10},
         {"sphere_radius": 10, "sessions": ["20200101-000000-nosuch@20"]},
         {"sphere_radius": 10, "sessions": [done + "@2O"]}, {"sphere_radius": 10, "sessions": [done + "@1e6"]},
         {"sphere_radius": 10, "sessions": [done]}, {"sphere_radius": 10, "sessions": [done + "@20", done + "@40"]},
         {"sphere_radius": 10, "plane_z_mm": "high"}, {"sphere_radius": -1},
         {"spheres": "13,12,9,0", "sessions": [done + "@20"]}, {"sphere_radius": 10, "sphere_cut": 12},
         {"sphere_radius": 10, "sphere_cut": 7, "hemispheres": True}, {"sphere_radius": 10, "hemispheres": "yes"},
         {"sphere_radius": 10, "sessions": "%s@20" % done},
         {"sphere_radius": 10, "sphere_cut": 7, "plane_z_mm": 0, "sessions": [done + "@20"], "dome": [30, 20, 0, 500]}]
out = []
for i, a in enumerate(cases):
    f.write(json.dumps({"id": i, "cmd": "calibrate", "args": {"routine": "lights", "args": a}}) + "\n"); f.flush()
    out.append(json.loads(f.readline()).get("error") or {})
print(json.dumps(out, indent=1))
PY
lights_err() {   # lights_err CASE CODE FIELD MESSAGE-PART
  check "lights case $1 refused: $2 naming $3" python3 -c '
import json, sys
e = json.load(open(sys.argv[1]))[int(sys.argv[2])]
ok = e.get("code") == sys.argv[3] and e.get("field") == sys.argv[4] and sys.argv[5] in e.get("message", "")
print("   ", e.get("code"), e.get("field"), e.get("message"))
sys.exit(not ok)' "$tmp/lights-args.json" "$@"
}
lights_err 0 bad_argument args.args.sphere_radius "needs sphere_radius or spheres"
lights_err 1 bad_argument args.args.sphere_radius "together with spheres"
lights_err 2 bad_argument "args.args.sessions[0]" "nosuch is not a completed session"
lights_err 3 bad_argument "args.args.sessions[0]" "board height after '@'"
lights_err 4 bad_argument "args.args.sessions[0]" "board height after '@'"
lights_err 5 bad_argument "args.args.sessions[0]" 'expected "ID@Z"'
lights_err 6 bad_argument "args.args.sessions[1]" "listed twice"
lights_err 7 bad_argument args.args.plane_z_mm "number of mm"
lights_err 8 bad_argument args.args.sphere_radius "above 0"
lights_err 9 bad_argument args.args.sessions "only together with sphere_radius"
lights_err 10 bad_argument args.args.sphere_cut "less than sphere_radius"
lights_err 11 bad_argument args.args.sphere_cut "together with hemispheres"
lights_err 12 bad_argument args.args.hemispheres "true or false"
lights_err 13 bad_argument args.args.sessions "expected a list"
lights_err 14 not_found args.plan "lights.cfg"
"$imp" status --socket "$sock" --json >"$tmp/status-after.json" 2>"$tmp/e"; rc=$?
check "the daemon keeps serving after the refusals" [ $rc -eq 0 ]
"$imp" calibrate list --socket "$sock" --json >"$tmp/list.json"
check "none of them started a calibration" [ "$(jget "$tmp/list.json" 'len(j["calibrations"])')" = 1 ]

# ---- a later scan references it and carries the calibrated sensor
"$imp" scan start "$tmp/plans/sweep.cfg" --name after --wait --socket "$sock" --json >"$tmp/scan.json" 2>"$tmp/e"; rc=$?
check "a scan after the calibration completes" [ $rc -eq 0 ]
set_dir=$(ls -d "$tmp"/state/sessions/*-after | head -1)
check "its set names calibration version 1" [ "$(jget "$set_dir/calibration.json" 'j["version"]')" = 1 ]
check "its rig.json carries the calibrated gain" \
  python3 -c "import json,sys; g=json.load(open('$set_dir/rig.json'))['cameras'][0]['sensor']['gain_e_per_dn']; sys.exit(abs(g-$gain) > 1e-9)"

# ---- the client follows a second calibration to the end
"$imp" calibrate start radiometric --follow --socket "$sock" >"$tmp/follow.txt" 2>&1; rc=$?
check "calibrate start --follow: exit 0 when done" [ $rc -eq 0 ]
check "--follow printed the capture progress and the figures" \
  sh -c "grep -q 'capture .*48/48 frames' '$tmp/follow.txt' && grep -q 'calibration 2 (radiometric): done' '$tmp/follow.txt' && grep -q 'sensor.gain_e_per_dn' '$tmp/follow.txt'"
"$imp" calibrate list --socket "$sock" --json >"$tmp/list.json"
check "version 2 is now in force" [ "$(jget "$tmp/list.json" 'j["current"]["version"]')" = 2 ]

# ---- the projector's gamma and black level (a white board under phase shifts), on top of
# version 2: the routine writes a copy of the set's rig, which carries version 2's sensor
"$imp" calibrate start projector-gamma --follow --socket "$sock" >"$tmp/follow-gamma.txt" 2>&1; rc=$?
check "calibrate start projector-gamma --follow: exit 0 when done" [ $rc -eq 0 ]
check "the routine ran calibrate radiometric --projector-set on the capture" \
  grep -q -- ' calibrate radiometric --projector-set [^ ]* --json ' "$tmp/state/calibrations/3/routine.log"
check "version 3 carries the estimated gamma (true 2.2) and black level (true 0.01), and version 2's sensor" \
  python3 - "$tmp/state/calibrations/3/rig.json" "$tmp/state/calibrations/2/rig.json" "$tmp/state/calibrations/3/report.json" <<'PY'
import json, sys
r3, r2, rep = (json.load(open(p)) for p in sys.argv[1:4])
g, b = r3["projector"]["gamma"], r3["projector"]["black_level"]
print("  gamma %.4f ± %.4f, black level %.5f" % (g, rep["projector"]["gamma_sigma"], b))
sys.exit(0 if abs(g / 2.2 - 1) < 0.005 and abs(b - 0.01) < 0.002 and abs(g - rep["projector"]["gamma"]) < 1e-8 * g
         and r3["cameras"][0]["sensor"] == r2["cameras"][0]["sensor"] else 1)
PY

# ---- lights with detection and an earlier session at 20 mm: the daemon hands the routine
# --set THIS --set SET@20 (a flat white board has no mirrors: the routine then refuses)
"$imp" calibrate start lights --plan "$tmp/plans/sweep.cfg" --arg sphere_radius=10 --arg sphere_cut=7 \
  --arg "sessions=[\"$session@20\"]" --arg plane_z_mm=0 --json --socket "$sock" >"$tmp/lights.json" 2>"$tmp/e"; rc=$?
check "calibrate start lights with a session at 20 mm: exit 0" [ $rc -eq 0 ]
check "calibration 4 fails (no mirrors on a flat board)" [ "$(calibrate_wait 4 300)" = failed ]
check "with the routine's own reason" grep -q "no mirror sphere found" "$tmp/show.json"
check "the routine got this capture, the session's set at 20 mm and the detection parameters" sh -c "
  grep -q -- ' calibrate lights --set $tmp/state/sessions/[^ ]* --set $tmp/state/sessions/$session@20 --json ' \
    '$tmp/state/calibrations/4/routine.log' && grep -q -- ' --sphere-radius 10 ' '$tmp/state/calibrations/4/routine.log' &&
  grep -q -- ' --sphere-cut 7 ' '$tmp/state/calibrations/4/routine.log'"
"$imp" calibrate list --socket "$sock" --json >"$tmp/list.json"
check "version 3 stays in force" [ "$(jget "$tmp/list.json" 'j["current"]["version"]')" = 3 ]

lib_finish
