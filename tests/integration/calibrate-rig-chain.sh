#!/bin/bash
# `impasto calibrate radiometric --rig BASE.json --out RIG.json` (the demo's
# calibration chain, docs/calibration.md): the sensor estimated from a photon-transfer set goes
# into a copy of BASE.json — not of the set's own rig — into BASE's camera of the same name;
# everything else of BASE is kept. A noisy flat-white set (config/plans/photon-transfer.cfg,
# 48 frames of 200 × 150, < 1 s to render). Refused: a BASE without that camera, --rig
# without --out.
# Usage: calibrate-rig-chain.sh BUILD_DIR SOURCE_DIR
set -u
bin=$1 src=$2
NAME=rig-chain
. "$src/tests/integration/lib-check.sh"
sed 's/effects = \["direct"\];/effects = ["direct", "noise"];/' "$src/config/scenes/flat-white.cfg" >"$tmp/scene.cfg"
grep -q '"noise"' "$tmp/scene.cfg" || { echo "FAIL flat-white.cfg no longer has the shape this test edits"; exit 1; }
"$imp" sim render --scene "$tmp/scene.cfg" --plan "$src/config/plans/photon-transfer.cfg" --out "$tmp/ptc" \
  --threads 2 --quiet >"$tmp/render.log" 2>&1 || { cat "$tmp/render.log"; echo "FAIL sim render"; exit 1; }
# BASE: the set's rig with markers (another focal length, projector gamma, a light moved and
# a wrong sensor gain that the estimate must replace); NOCAM: its camera renamed.
marked_base "$tmp/ptc/rig.json" "$tmp/base.json" "$tmp/nocam.json"
"$imp" calibrate radiometric --set "$tmp/ptc" --rig "$tmp/base.json" --out "$tmp/out.json" >"$tmp/o" 2>"$tmp/e"
check "radiometric --rig BASE --out: exit 0" [ $? -eq 0 ]
"$imp" calibrate radiometric --set "$tmp/ptc" --out "$tmp/own.json" >"$tmp/o" 2>"$tmp/e"
check "radiometric --out without --rig: exit 0" [ $? -eq 0 ]
check "out.json: BASE's camera model, projector and lights kept; the sensor estimated (gain within 3 % of 2.5)" \
  python3 - "$tmp/out.json" "$tmp/base.json" <<'PY'
import json, sys
o, b = (json.load(open(p)) for p in sys.argv[1:3])
c = o["cameras"][0]
ok = (c["model"] == b["cameras"][0]["model"] and o["projector"] == b["projector"] and o["lights"] == b["lights"]
      and abs(c["sensor"]["gain_e_per_dn"] / 2.5 - 1) < 0.03 and abs(c["sensor"]["black_level_dn"] - 64) < 0.5)
print("  gain %.4f, black %.3f, fx %g, gamma %g" % (c["sensor"]["gain_e_per_dn"], c["sensor"]["black_level_dn"],
                                                   c["model"]["fx"], o["projector"]["gamma"]))
sys.exit(0 if ok else 1)
PY
check "own.json (no --rig): the set's rig with the same sensor" python3 - "$tmp/own.json" "$tmp/out.json" "$tmp/ptc/rig.json" <<'PY'
import json, sys
o, c, s = (json.load(open(p)) for p in sys.argv[1:4])
sys.exit(0 if (o["cameras"][0]["model"] == s["cameras"][0]["model"] and o["projector"] == s["projector"]
               and o["cameras"][0]["sensor"] == c["cameras"][0]["sensor"]) else 1)
PY
"$imp" calibrate radiometric --set "$tmp/ptc" --rig "$tmp/nocam.json" --out "$tmp/bad.json" >"$tmp/o" 2>"$tmp/e"
rc=$?
check "a BASE without the set's camera: refused (exit $rc), named, nothing written" \
  sh -c "[ $rc -ne 0 ] && grep -q \"no camera 'cam0'\" '$tmp/e' && [ ! -e '$tmp/bad.json' ]"
"$imp" calibrate radiometric --set "$tmp/ptc" --rig "$tmp/base.json" >"$tmp/o" 2>"$tmp/e"
check "--rig without --out: usage error (exit 2)" [ $? -eq 2 ]
finish
