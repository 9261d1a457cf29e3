#!/bin/bash
# `impasto calibrate radiometric --projector-set`: the projector's gamma from a
# flat white board under white, black and 8 phase-shift frames (config/scenes/
# projector-gamma-demo.cfg through a 200 × 150 window of its camera, same 50 µm pixels;
# config/plans/projector-gamma.cfg, 11 frames, ~1 s each render). Two projectors, gamma 2.2
# and 1.8, so that no fixed answer passes; tolerance 0.2 % of gamma, and the error within
# 4 gamma_sigma (measured on this window: −0.016 % and −0.017 %, each 1.0 gamma_sigma;
# docs/calibration-lights.md).
# The written rig is BASE with projector.gamma replaced and nothing else; --set and
# --projector-set together keep the photon-transfer report's keys at the top level. Refused
# with exit 3 and what is missing named: a set without phase frames, without white and
# black. A gamma outside the search's bounds (7) is flagged at_bound, exit 6, and BASE's
# gamma is kept.
# Usage: calibrate-projector-gamma.sh BUILD_DIR SOURCE_DIR
set -u
bin=$1 src=$2
NAME=gamma
. "$src/tests/integration/lib-check.sh"
scene=$src/config/scenes/projector-gamma-demo.cfg
plan=$src/config/plans/projector-gamma.cfg
# SCENE GAMMA OUT [BLACK]: the demo target through a 200 × 150 window, the projector at GAMMA
# (and black level BLACK, default the scene's 0.01)
window() {
  sed -e 's/width = 1400; height = 1000;/width = 200; height = 150;/' -e "s/gamma = 2.2;/gamma = $2;/" \
    -e "s/black_level = 0.01;/black_level = ${4:-0.01};/" "$scene" >"$3"
  grep -q 'width = 200; height = 150;' "$3" && grep -q "gamma = $2;" "$3" && grep -q "black_level = ${4:-0.01};" "$3" ||
    { echo "FAIL $scene no longer has the shape this test edits"; exit 1; }
}
render() {   # SCENE PLAN OUT
  "$imp" sim render --scene "$1" --plan "$2" --out "$3" --threads 2 --quiet >"$tmp/render.log" 2>&1 ||
    { cat "$tmp/render.log"; echo "FAIL sim render $1 $2"; exit 1; }
}

declare -A black=([2.2]=0.01 [1.8]=0.04)
for g in 2.2 1.8; do
  window "$scene" $g "$tmp/s$g.cfg" ${black[$g]}
  render "$tmp/s$g.cfg" "$plan" "$tmp/set$g"
  # BASE: the set's rig with markers the estimate must not touch, and a wrong gamma
  marked_base "$tmp/set$g/rig.json" "$tmp/base$g.json"
  "$imp" calibrate radiometric --projector-set "$tmp/set$g" --json --rig "$tmp/base$g.json" --out "$tmp/out$g.json" \
    >"$tmp/j$g" 2>"$tmp/e"
  rc=$?
  check "gamma $g: exit 0 (got $rc)" [ $rc -eq 0 ]
  check "gamma $g: estimate within 0.2 % and 4 sigma, black level within 0.001, report complete, no flags" \
    python3 - "$tmp/j$g" $g ${black[$g]} <<'PY'
import json, sys
p = json.load(open(sys.argv[1]))["projector"]
truth, black = float(sys.argv[2]), float(sys.argv[3])
print("  black level %.5f (truth %g), sensor black %.2f DN" % (p["black_level"], black, p["sensor_black_dn"]))
print("  gamma %.4f ± %.4f (truth %g, error %+.2f %%), %d pixels, bin %d, %d blocks, min contrast %.0f DN"
      % (p["gamma"], p["gamma_sigma"], truth, 100 * (p["gamma"] / truth - 1), p["pixels"], p["bin"], p["blocks"],
         p["min_contrast_dn"]))
err = p["gamma"] - truth
ok = (abs(err / truth) < 0.002 and abs(err) < 4 * p["gamma_sigma"] and p["steps"] == 8 and p["period_px"] == 256 and p["axis"] == "x"
      and p["exposure_us"] == 16000 and p["pixels"] > 20000 and p["flags"] == []
      and 0 < p["gamma_sigma"] < 0.002 and p["blocks"] >= 4 and abs(p["black_level"] - black) < 0.001)
sys.exit(0 if ok else 1)
PY
  check "gamma $g: out.json is BASE with projector.gamma, black_level = the reported ones, nothing else changed" \
    python3 - "$tmp/out$g.json" "$tmp/base$g.json" "$tmp/j$g" <<'PY'
import json, sys
o, b, j = (json.load(open(p)) for p in sys.argv[1:4])
g = j["projector"]["gamma"]
og, ob = o["projector"].pop("gamma"), o["projector"].pop("black_level")
b["projector"].pop("gamma"); b["projector"].pop("black_level")
sys.exit(0 if abs(og - g) <= 1e-9 * g and abs(ob - j["projector"]["black_level"]) <= 1e-9 and o == b else 1)
PY
done
"$imp" calibrate radiometric --projector-set "$tmp/set1.8" >"$tmp/o" 2>"$tmp/e"
check "text output: one line with the gamma" sh -c "[ \$(grep -c 'projector proj .*gamma 1\.[0-9]* ± ' '$tmp/o') -eq 1 ]"

# both sets: the photon-transfer report keeps its top-level keys, the projector beside it
sed 's/effects = \["direct"\];/effects = ["direct", "noise"];/' "$src/config/scenes/flat-white.cfg" >"$tmp/ptc.cfg"
render "$tmp/ptc.cfg" "$src/config/plans/photon-transfer.cfg" "$tmp/ptc"
"$imp" calibrate radiometric --set "$tmp/ptc" --projector-set "$tmp/set2.2" --json --rig "$tmp/base2.2.json" \
  --out "$tmp/both.json" >"$tmp/jb" 2>"$tmp/e"
rc=$?
check "--set and --projector-set: exit 0 (got $rc); sensor and gamma both written" \
  python3 - "$tmp/jb" "$tmp/both.json" "$tmp/base2.2.json" <<'PY'
import json, sys
j, o, b = (json.load(open(p)) for p in sys.argv[1:4])
ok = ("gain_sigma_e_per_dn" in j and "flags" in j and "sensor" in j and "points" in j
      and abs(j["projector"]["gamma"] / 2.2 - 1) < 0.002
      and abs(o["cameras"][0]["sensor"]["gain_e_per_dn"] / 2.5 - 1) < 0.03
      and abs(o["projector"]["gamma"] - j["projector"]["gamma"]) <= 1e-9 * j["projector"]["gamma"])
ok = ok and o["cameras"][0]["model"] == b["cameras"][0]["model"] and o["lights"] == b["lights"]
sys.exit(0 if ok else 1)
PY

# a set without phase frames, one without white and black
cat >"$tmp/nophase.cfg" <<'EOF'
structured_light = { gray_bits = 1; inverse = false; axes = ["x"]; exposures_us = [16000.0]; };
EOF
sed -e 's/white = true;/white = false;/' -e 's/black = true;/black = false;/' "$plan" >"$tmp/nowb.cfg"
grep -q 'white = false;' "$tmp/nowb.cfg" || { echo "FAIL $plan no longer has the shape this test edits"; exit 1; }
render "$tmp/s2.2.cfg" "$tmp/nophase.cfg" "$tmp/nophase"
render "$tmp/s2.2.cfg" "$tmp/nowb.cfg" "$tmp/nowb"
# a scene that renders no projector light: every frame is noise around the sensor's black
sed 's/"projector", //' "$tmp/s2.2.cfg" >"$tmp/nolight.cfg"
grep -q '"projector"' "$tmp/nolight.cfg" && { echo "FAIL $scene no longer has the shape this test edits"; exit 1; }
render "$tmp/nolight.cfg" "$plan" "$tmp/nolight"
"$imp" calibrate radiometric --projector-set "$tmp/nolight" --rig "$tmp/base2.2.json" --out "$tmp/bad.json" \
  >"$tmp/o" 2>"$tmp/e"
rc=$?
check "no projector light: exit 3 (got $rc), said so with the contrast against the noise, nothing written" \
  sh -c "[ $rc -eq 3 ] && grep -q 'against a noise of .* DN: the projector does not light the target' '$tmp/e' && [ ! -e '$tmp/bad.json' ]"
"$imp" calibrate radiometric --projector-set "$tmp/nophase" --rig "$tmp/base2.2.json" --out "$tmp/bad.json" \
  >"$tmp/o" 2>"$tmp/e"
rc=$?
check "no phase frames: exit 3 (got $rc), the set and what is missing named, nothing written" \
  sh -c "[ $rc -eq 3 ] && grep -q '$tmp/nophase: no phase-shift frames of camera cam0' '$tmp/e' && [ ! -e '$tmp/bad.json' ]"
"$imp" calibrate radiometric --projector-set "$tmp/nowb" --out "$tmp/bad.json" >"$tmp/o" 2>"$tmp/e"
rc=$?
check "no white and black: exit 3 (got $rc), both named" \
  sh -c "[ $rc -eq 3 ] && grep -q '$tmp/nowb: .*missing the white frame, the black frame' '$tmp/e' && [ ! -e '$tmp/bad.json' ]"
[ $fails -eq 0 ] || cat "$tmp/e"

# gamma 7: outside the search's [0.3, 5]: flagged, exit 6, BASE's gamma kept
window "$scene" 7.0 "$tmp/s7.cfg"
render "$tmp/s7.cfg" "$plan" "$tmp/set7"
"$imp" calibrate radiometric --projector-set "$tmp/set7" --json --rig "$tmp/base2.2.json" --out "$tmp/out7.json" \
  >"$tmp/j7" 2>"$tmp/e"
rc=$?
check "gamma 7: exit 6 (got $rc), flagged at_bound with a warning, BASE's gamma 2.9 kept" \
  python3 - "$tmp/j7" "$tmp/out7.json" "$tmp/e" $rc <<'PY'
import json, sys
j, o = (json.load(open(p)) for p in sys.argv[1:3])
sys.exit(0 if (int(sys.argv[4]) == 6 and "at_bound" in j["projector"]["flags"] and o["projector"]["gamma"] == 2.9
               and "not determined" in open(sys.argv[3]).read()) else 1)
PY

"$imp" calibrate radiometric --json >"$tmp/o" 2>"$tmp/e"
check "neither --set nor --projector-set: usage error (exit 2)" [ $? -eq 2 ]
finish
