#!/usr/bin/env bash
# `impasto plan estimate` of a whole painting against the simulator's clock (the figure `sim
# render --painting` and `sim serve` report; `sim info --plan` computes it from the plan and
# the scene's gantry without rendering a frame: simulated time, not wall time): within 10 %
# for both painting plans, and for a gantry 10 times slower with a 2 s settle, whose moves
# then outweigh the frames (the estimate must take its moves from the scene, not from the
# defaults of a 50 mm/s stage). The frames' share is checked alone too: the estimate without
# moves against the clock minus the simulator's gantry moves.
# Usage: painting-estimate-clock.sh BUILD_DIR SOURCE_DIR
set -euo pipefail
bin=$1
src=$2
NAME=painting-estimate-clock
. "$src/tests/integration/lib-check.sh"

# within SCENE PLAN: the estimate's capture_s and move_s against the simulated clock and moves.
within() {
  "$imp" plan estimate "$2" --scene "$1" --json --target "$tmp" >"$tmp/est.json" || return 1
  "$imp" sim info --scene "$1" --plan "$2" >"$tmp/info.txt" || return 1
  python3 - "$tmp/est.json" "$tmp/info.txt" <<'PY'
import json, re, sys
p = json.load(open(sys.argv[1]))["painting"]
m = re.search(r"^painting: (\d+) tiles, simulated clock ([\d.]+) s \(gantry moves ([\d.]+) s\)$",
              open(sys.argv[2]).read(), re.M)
if not m:
    sys.exit("sim info printed no simulated clock")
tiles, clock, moves = int(m[1]), float(m[2]), float(m[3])
frames_est, frames_sim = p["capture_s"] - p["move_s"], clock - moves
print("   %d tiles: estimate %.2f s (moves %.2f s), simulated clock %.2f s (moves %.2f s): %+.1f %%, frames %+.1f %%"
      % (tiles, p["capture_s"], p["move_s"], clock, moves, 100 * (p["capture_s"] - clock) / clock,
         100 * (frames_est - frames_sim) / frames_sim))
ok = tiles == p["tiles"] and clock > 0 and abs(p["capture_s"] - clock) <= 0.10 * clock \
     and abs(frames_est - frames_sim) <= 0.10 * frames_sim and (moves == 0) == (p["move_s"] == 0)
sys.exit(0 if ok else 1)
PY
}

check "painting-small: estimate within 10 % of the simulated clock" \
  within "$src/config/scenes/painting-small.cfg" "$src/config/plans/painting-small.cfg"
check "painting-300x200: estimate within 10 % of the simulated clock" \
  within "$src/config/scenes/painting-300x200.cfg" "$src/config/plans/painting-300x200.cfg"
# A slow gantry: 5 mm/s, 2 s settle (moves ~40 s against ~7 s of frames on painting-small).
sed -e 's/speed_mm_s = [0-9.]*;/speed_mm_s = 5.0;/' -e 's/settle_s = [0-9.]*;/settle_s = 2.0;/' \
  "$src/config/scenes/painting-small.cfg" >"$tmp/slow-gantry.cfg"
check "the slow gantry scene differs from painting-small" \
  bash -c "grep -q 'speed_mm_s = 5.0;' '$tmp/slow-gantry.cfg' && grep -q 'settle_s = 2.0;' '$tmp/slow-gantry.cfg'"
check "a slow gantry: estimate within 10 % of the simulated clock" \
  within "$tmp/slow-gantry.cfg" "$src/config/plans/painting-small.cfg"
finish
