#!/bin/bash
# impastod calibrates the dome lights of the emulated rig the way an operator
# would with one mirror target and two spacer blocks: the board raised 40 mm
# (config/scenes/lights-target-raised.cfg) and 20 mm (lights-target-mid.cfg) is each captured
# as an ordinary session of config/plans/lights.cfg (one frame per light, darks); then, with
# the board on the canvas (lights-target.cfg), `impasto calibrate start lights` with mirror
# detection (sphere_radius 10, sphere_cut 7: no positions given) and the two sessions at 40
# and 20 mm (`sessions`, "ID@Z") captures the third set, runs `impasto calibrate lights
# --set A --set B@20 --set C@40 …` and stores calibration version 1. Compared with the served
# rig's truth: all 56 lights located, none ill-conditioned; the free triangulation
# (report.json) RMS within 0.6 mm, worst within 1.5 mm, each light within 3σ of its own
# covariance; on the dome (`dome`, rig.json, in force) within 0.2 mm, the issue's 1 mm with
# room; intensities within 2 % (measured in three runs: free RMS 0.415/0.439/0.445 mm, worst
# 0.856/1.014/0.966 mm; dome 0.051/0.049/0.056 mm; 0.06 %; with the 48-light dome of before
# the 80° ring and before the joint refinement; with 56 lights and the joint refinement, one
# run: RMS 0.257 mm, worst 0.575 mm, dome worst 0.047 mm, 0.05 %, 157 s). Three renders of 60 frames at 0.02 mm: 110 s at load 2, 288-397 s at load
# 7-12 on 2 cores (52 frames then), labelled slow (tests/daemon-calibrate.cmake, timeout
# 1200 s).
# Usage: daemon-calibrate-lights.sh BUILD_DIR SOURCE_DIR MODBUS_PORT
set -u
build=$1 src=$2 port=$3
. "$src/tests/integration/lib-daemon.sh"
lib_init calibrate-lights
# the emulated camera renders a frame of these 0.02 mm scenes far slower than a grab may take
# when built with the sanitizers: the daemon loses the camera (ENOTCONN) after a few
# timeouts. The daemon's side of this routine runs under them in test-daemon-calibrate.
if grep -q '^IMPASTO_SANITIZE:BOOL=ON' "$build/CMakeCache.txt" 2>/dev/null; then
  echo "SKIP: a sanitizer build renders too slowly for the emulated camera"; exit 77
fi
mkdir -p "$tmp/plans"
cp "$src/config/plans/lights.cfg" "$tmp/plans/"
t0=$(date +%s)

# seeds as in the scenes (test-calib-lights-sim renders the same three)
capture_scene "$src/config/scenes/lights-target-raised.cfg" 9 "$tmp/plans/lights.cfg" raised40 1500
raised=$captured
capture_scene "$src/config/scenes/lights-target-mid.cfg" 10 "$tmp/plans/lights.cfg" mid20 1500
mid=$captured

serve_start "$src/config/scenes/lights-target.cfg" 8
daemon_start --calibrate-cmd "$imp" --retries 10
"$imp" calibrate start lights --arg sphere_radius=10 --arg sphere_cut=7 --arg plane_z_mm=0 \
  --arg "sessions=[\"$mid@20\",\"$raised@40\"]" --arg 'dome=[30,20,0,500]' --json \
  --socket "$sock" >"$tmp/start.json" 2>"$tmp/e"; rc=$?
check "calibrate start lights, detection and 2 earlier sessions: exit 0" [ $rc -eq 0 ]
[ $rc -eq 0 ] || cat "$tmp/e"
check "calibration 1 ends done" [ "$(calibrate_wait 1 1500)" = done ]
check "and is in force" [ "$(jget "$tmp/show.json" 'j["current"]')" = True ]
check "the routine got the three sets with their heights, and detection" sh -c "
  grep -q -- ' --set $tmp/state/sessions/[^ ]* --set $tmp/state/sessions/$mid@20 --set $tmp/state/sessions/$raised@40 ' \
    '$tmp/state/calibrations/1/routine.log' && grep -q -- ' --sphere-radius 10 ' '$tmp/state/calibrations/1/routine.log' &&
  grep -q -- ' --sphere-cut 7 ' '$tmp/state/calibrations/1/routine.log'"
check "56 lights in the report, all located" \
  [ "$(jget "$tmp/show.json" 'j["figures"]["lights.count"], j["figures"]["lights.located.true"]')" = "(56, 56)" ]
# truth: the served rig (the same dome in the three scenes); free positions and their
# covariances from the report, dome-constrained ones (what --dome puts into rig.json) from the
# stored rig
python3 - "$tmp/rig.json" "$tmp/state/calibrations/1/report.json" "$tmp/state/calibrations/1/rig.json" \
  >"$tmp/compare.txt" <<'PY'
import json, math, sys
truth = json.load(open(sys.argv[1]))["lights"]
report = json.load(open(sys.argv[2]))["lights"]
rig = json.load(open(sys.argv[3]))["lights"]
def det(m): return (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
                    + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
def mahalanobis2(e, c):   # eᵀC⁻¹e, C solved by Cramer's rule
    m = [c[0:3], c[3:6], c[6:9]]
    x = [det([[e[k] if j == i else m[k][j] for j in range(3)] for k in range(3)]) / det(m) for i in range(3)]
    return sum(a * b for a, b in zip(e, x))
free, m2 = [], []
for t, r in zip(truth, report):
    if r.get("located"):
        e = [a - b for a, b in zip(r["pos_mm"], t["pos_mm"])]
        free.append(math.hypot(*e))
        m2.append(mahalanobis2(e, r["cov_mm2"]))
dome = [math.dist(t["pos_mm"], e["pos_mm"]) for t, e in zip(truth, rig)]
irel = [abs(e["intensity"] / t["intensity"] - 1) for t, e in zip(truth, rig)]
flagged = sum(r.get("flags", {}).get("ill_conditioned", False) for r in report)
rms = math.sqrt(sum(d * d for d in free) / len(free))
print(f"{len(truth)} {len(report)} {len(free)} {max(free):.3f} {rms:.3f} {max(m2):.2f} {sum(m2) / len(m2):.2f}"
      f" {max(dome):.4f} {max(irel):.5f} {flagged}")
PY
read -r ntruth nreport nfree free_worst free_rms m2_worst m2_mean dome_worst irel flagged <"$tmp/compare.txt"
echo "daemon light calibration, 3 captures (0/20/40 mm): free worst $free_worst mm, RMS $free_rms mm" \
     "($nfree located, $flagged ill-conditioned; Mahalanobis² worst $m2_worst, mean $m2_mean); on the dome worst" \
     "$dome_worst mm; intensity worst $irel relative; $(( $(date +%s) - t0 )) s"
check "every light of the truth compared, located in the report" [ "$ntruth/$nreport/$nfree" = 56/56/56 ]
check "no light ill-conditioned with three board heights" [ "$flagged" = 0 ]
# The free fit's predicted σ is 0.33-0.6 mm per light, so its worst of 56 lands near 1 mm
# (0.86, 1.01, 0.97 mm in three runs, 0.92 offline): the test holds the RMS, each light to its own
# 3σ (eᵀC⁻¹e < 14.2, χ² with 3 degrees of freedom at 99.7 %), and the worst to 1.5 mm; the
# issue's 1 mm is held by the positions in force, those on the dome.
check "free triangulation RMS within 0.6 mm of the truth" python3 -c "import sys; sys.exit(not $free_rms < 0.6)"
check "free triangulation worst within 1.5 mm" python3 -c "import sys; sys.exit(not $free_worst < 1.5)"
check "every free position within 3σ of its own covariance" python3 -c "import sys; sys.exit(not $m2_worst < 14.2)"
check "on the dome (rig.json, in force) within 0.2 mm: the issue's 1 mm" python3 -c "import sys; sys.exit(not $dome_worst < 0.2)"
check "intensities within 2 % of the truth" python3 -c "import sys; sys.exit(not $irel < 0.02)"
lib_finish
