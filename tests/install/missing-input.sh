#!/bin/sh
# missing-input.sh BUILD SRC: every command given an input that does not exist exits 3 (bad
# input, pipeline/core/exit-codes.h) at once, naming the path, and writes nothing. One row per
# command and input; a command that hangs (served anyway), exits 1/2 or stays silent fails its
# row. Commands that talk to impastod are not here: the daemon resolves their paths (exit 4
# without it).
set -u
build=$1 src=$2
imp=$build/cli/impasto
[ -x "$imp" ] || { echo "SKIP: $imp not built"; exit 77; }
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-missing.XXXXXX") || exit 2
trap 'rm -rf "$tmp"' EXIT
N=$tmp/nonexist scene=$src/config/scenes/small.cfg plan=$src/config/plans/small.cfg
failures=0 rows=0
# row "ARGS" (the missing path is always $N): exit 3 within 20 s, $N named on stderr, no $tmp/out*
row() {
  rows=$((rows + 1))
  # shellcheck disable=SC2086
  timeout 20 "$imp" $1 >"$tmp/o" 2>"$tmp/e" </dev/null
  rc=$?
  if [ $rc -eq 3 ] && grep -qF "$N" "$tmp/e" && ! ls -d "$tmp"/out* >/dev/null 2>&1; then
    echo "ok: impasto $1 -> 3"
  else
    echo "FAIL: impasto $1 -> exit $rc (expected 3, naming $N, nothing written)"; sed 's/^/    /' "$tmp/e" | head -3
    failures=$((failures + 1)); rm -rf "$tmp"/out*
  fi
}
row "process $N --out $tmp/out"
row "compare $N --truth $N"
row "render $N --view 0,0,50 --light 0,0,50 --out $tmp/out.png"
row "view $N --port 0"
row "export $N --to ply --out $tmp/out"
row "repair $N"
row "mosaic $N --out $tmp/out"
row "import photometric --images $N --lights $N --out $tmp/out"
row "import sl --frames $N --order opencv-graycode --projector 800x600 --calib $N --out $tmp/out"
row "compare-normals $N --truth-normals $N"
row "plan validate $N --scene $scene"
row "plan estimate $N --scene $scene"
row "plan estimate $plan --scene $N"
row "plan estimate $plan --rig $N"
row "sim render --scene $N --plan $plan --out $tmp/out"
row "sim render --scene $scene --plan $N --out $tmp/out"
row "sim serve --scene $N --address 127.0.0.1"
row "calibrate camera --images $N --board 9x6 --square 10"
row "calibrate procam --sets $N --board 9x6 --square 10"
row "calibrate lights --set $N --sphere-radius 10"
row "calibrate radiometric --set $N"
row "bench tile $N --out $tmp/out"
[ $failures -eq 0 ] || { echo "$failures of $rows rows failed"; exit 1; }
echo "$rows commands: a missing input exits 3"
