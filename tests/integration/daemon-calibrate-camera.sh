#!/bin/bash
# impastod calibrates camera and projector from board poses: the emulated rig
# shows one chessboard pose per `impasto sim serve` (config/scenes/target-K.cfg), so the
# board is "moved" by serving the next scene, as an operator would move it between captures.
# Poses 3, 8 and 10 are captured as ordinary sessions of config/plans/target.cfg; then
# `impasto calibrate start camera` with the flat reference pose (target-0) served captures it
# and runs `impasto calibrate procam --sets` on all four sets (`sessions`), with this capture
# as the canvas reference (`board_origin`). The calibration must end done, in force, with the
# camera's fx, fy within 1 % and principal point within 10 px of the served truth (4 poses,
# not the 14 of test-calib-sim: looser than the issue's 0.1 %). A calibration of one pose
# fails with the routine's own message. A capture that pauses on a device fault (grabs time
# out when the machine is loaded) is resumed by the script, as an operator would. About 5 minutes, mostly rendering: slow.
# Usage: daemon-calibrate-camera.sh BUILD_DIR SOURCE_DIR MODBUS_PORT
set -u
build=$1 src=$2 port=$3
. "$src/tests/integration/lib-daemon.sh"
lib_init calibrate-camera
mkdir -p "$tmp/plans"
cp "$src/config/plans/target.cfg" "$tmp/plans/"

stop_all() {
  kill -TERM "$daemon_pid" "$serve_pid" 2>/dev/null
  wait "$daemon_pid" "$serve_pid" 2>/dev/null
  daemon_pid="" serve_pid=""
}
sessions=""
for k in 3 8 10; do
  serve_start "$src/config/scenes/target-$k.cfg" $((11 + k))
  daemon_start --calibrate-cmd "$imp" --retries 10
  "$imp" scan start "$tmp/plans/target.cfg" --name "pose$k" --json --socket "$sock" >"$tmp/pose$k.json" 2>"$tmp/e"
  id=$(jget "$tmp/pose$k.json" 'j["session"]')
  check "pose $k captured" [ "$(session_wait "$id" 900)" = completed ]
  sessions="$sessions${sessions:+,}\"$id\""
  stop_all
done

serve_start "$src/config/scenes/target-0.cfg" 11
daemon_start --calibrate-cmd "$imp" --retries 10
"$imp" calibrate start camera --arg board=15x8 --arg square=3 --arg "sessions=[$sessions]" \
  --arg board_origin=9,9.5 --json --socket "$sock" >"$tmp/start.json" 2>"$tmp/e"; rc=$?
check "calibrate start camera on 4 poses: exit 0" [ $rc -eq 0 ]
check "calibration 1 ends done" [ "$(calibrate_wait 1 1500)" = done ]
check "and is in force" [ "$(jget "$tmp/show.json" 'j["current"]')" = True ]
python3 - "$tmp/rig.json" "$tmp/state/calibrations/1/rig.json" "$tmp/show.json" >"$tmp/compare.txt" <<'PY'
import json, sys
t, e = (json.load(open(p))["cameras"][0] for p in sys.argv[1:3])
f = json.load(open(sys.argv[3]))["figures"]
def m(c, k): return c.get("model", c)[k]
print(" ".join(f"{v:.6g}" for v in (m(e, "fx") / m(t, "fx") - 1, m(e, "fy") / m(t, "fy") - 1,
                                      abs(m(e, "cx") - m(t, "cx")), abs(m(e, "cy") - m(t, "cy")),
                                      f.get("camera.rms_px", -1))))
PY
read -r dfx dfy dcx dcy rms <"$tmp/compare.txt"
echo "daemon camera calibration, 4 poses: fx ${dfx} fy ${dfy} (relative), cx ${dcx} px cy ${dcy} px off; RMS ${rms} px"
check "fx and fy within 1 % of the truth" python3 -c "import sys; sys.exit(not (abs($dfx) < 0.01 and abs($dfy) < 0.01))"
check "principal point within 10 px" python3 -c "import sys; sys.exit(not ($dcx < 10 and $dcy < 10))"
check "the reprojection RMS is in the figures" python3 -c "import sys; sys.exit(not (0 < $rms < 1))"

# one pose alone: the routine's own refusal, no new version in force
"$imp" calibrate start camera --arg board=15x8 --arg square=3 --socket "$sock" >"$tmp/one.txt" 2>&1
check "one pose: calibration 2 fails" [ "$(calibrate_wait 2 1500)" = failed ]
check "with the routine's reason" grep -q 'at least 3 needed' "$tmp/show.json"
"$imp" calibrate list --json --socket "$sock" >"$tmp/list.json"
check "version 1 stays in force" [ "$(jget "$tmp/list.json" 'j["current"]["version"]')" = 1 ]
lib_finish
