#!/usr/bin/env bash
# scripts/demo-painting on painting-small through impastod and the emulated gantry (or
# --offline), so that the demo cannot rot silently: it must finish, print its figures table,
# and the figures (DEMO_SUMMARY_JSON) must be sane: every tile captured and its job done,
# the mosaic covering every texel of the painting once, the registered placement's error
# below the stage prior's, the estimate within 10 % of the simulated clock.
# Usage: painting-demo.sh BUILD_DIR SOURCE_DIR MODBUS_PORT [--offline]
set -euo pipefail
bin=$1
src=$2
port=$3
mode=${4:-}
NAME=painting-demo
. "$src/tests/integration/lib-check.sh"
[ -n "$mode" ] || [ -x "$bin/daemon/impastod" ] || { echo "skip: impastod not built"; exit 77; }

scale=${IMPASTO_TIMEOUT_SCALE:-1}
rc=0
DEMO_SUMMARY_JSON=$tmp/summary.json "$src/scripts/demo-painting" --no-build --build-dir "$bin" --out "$tmp/demo" \
  --modbus-port "$port" --timeout $((1800 * scale)) $mode >"$tmp/demo.txt" 2>&1 || rc=$?
cat "$tmp/demo.txt"
if grep -q "port in use" "$tmp/demo.txt" && [ $rc -ne 0 ]; then
  echo "skip: the GigE Vision port is held by another process"; exit 77
fi
check "the demo finished (exit 0)" test $rc -eq 0
if [ -z "$mode" ]; then
  # scan --follow says when the stage moves (the frame count stands still meanwhile)
  check "scan --follow named the stage's moves" \
    bash -c "grep -q '^session [^ ]*: homing' '$tmp/demo.txt' && grep -q '^session [^ ]*: moving to tile 5 (col' '$tmp/demo.txt'"
fi
check "it printed the figures table" \
  bash -c "grep -q '^mosaic  *registered  *stage prior  *target' '$tmp/demo.txt' && \
           grep -q '^registration rms' '$tmp/demo.txt' && grep -q '^canvas covered' '$tmp/demo.txt' && \
           grep -q '^seam step rms' '$tmp/demo.txt' && grep -q '^height RMSE' '$tmp/demo.txt' && \
           grep -q '^far corner/mean' '$tmp/demo.txt'"
sane() {
  python3 - "$tmp/summary.json" "$mode" <<'PY'
import json, math, sys
s = json.load(open(sys.argv[1]))
reg, pri = s["registered"], s["prior"]
bad = []
def need(cond, what):
    if not cond:
        bad.append(what)
need(s["tiles"] == 9, "9 tiles (3 x 3: the plan's 1 mm edge margin), got %s" % s["tiles"])
need(s["jobs_done"] == s["tiles"], "every tile's job done: %s of %s" % (s["jobs_done"], s["tiles"]))
if s["mode"] == "daemon":
    need(s["frames_captured"] == s["frames"], "every frame captured: %s of %s" % (s["frames_captured"], s["frames"]))
    need(s["session_state"] == "completed", "session completed, is %s" % s["session_state"])
    need(s["capture_wall_s"] > 0 and s["sim_clock_s"] > 0, "capture wall time and simulated clock reported")
for k in ("reg_um", "abs_um", "seam_um", "height_rmse_um", "far_ratio", "covered_pct"):
    need(k in reg and k in pri and math.isfinite(reg[k]) and math.isfinite(pri[k]), "%s printed for both" % k)
if not bad:
    # The plan's outer fields pass the painting by 1 mm: every texel of the extent covered, once.
    need(reg.get("uncovered") == 0 and pri.get("uncovered") == 0, "every texel covered: %s / %s uncovered (%.3f / %.3f %%)"
         % (reg.get("uncovered"), pri.get("uncovered"), reg["covered_pct"], pri["covered_pct"]))
    need(reg["doubled"] == 0, "no texel doubled, got %d" % reg["doubled"])
    need(reg["reg_um"] < pri["reg_um"], "registered error %.1f um below the stage prior's %.1f um"
         % (reg["reg_um"], pri["reg_um"]))
    need(reg["height_rmse_um"] < 30, "height RMSE %.1f um under 30 um" % reg["height_rmse_um"])
    need(abs(s["estimate_capture_s"] - s["sim_clock_s"]) <= 0.1 * s["sim_clock_s"],
         "estimate %.1f s within 10 %% of the simulated clock %.1f s" % (s["estimate_capture_s"], s["sim_clock_s"]))
for b in bad:
    print("   not sane:", b)
sys.exit(1 if bad else 0)
PY
}
check "the figures are sane (summary JSON)" sane
# ([i], [s]: the pattern must not match a command line that holds the pattern itself)
no_leftovers() {
  ! pgrep -f "[i]mpastod --rig $tmp/demo/" >/dev/null && ! pgrep -f "[s]im serve .*$tmp/demo/" >/dev/null
}
check "no daemon or emulator left running from the demo's directory" no_leftovers
finish
