# Shared by the impasto-command integration scripts (calibrate-*.sh): source it after setting
# bin (the build directory) and NAME; it sets imp, a fresh $tmp removed on exit, and
# check WHAT CMD... (prints ok/FAIL, counts failures); finish exits 1 when any failed.
# Exits 77 (skip) when the impasto binary or python3 is missing.
imp=$bin/cli/impasto
[ -x "$imp" ] || { echo "skip: $imp not built"; exit 77; }
command -v python3 >/dev/null || { echo "skip: no python3"; exit 77; }
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-$NAME.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
fails=0
check() {
  local what=$1; shift
  if "$@"; then echo "ok   $what"; else echo "FAIL $what"; fails=$((fails + 1)); fi
}
finish() {
  [ $fails -eq 0 ] || { echo "$fails check(s) failed"; exit 1; }
  echo "all checks passed"
}
# marked_base RIG OUT [NOCAM]: RIG with markers an estimate must replace or keep (camera fx
# 1234.5, sensor gain 9.9, projector gamma 2.9, light 0 at (1, 2, 3)) into OUT; NOCAM: the
# same with its camera renamed "other".
marked_base() {
  python3 - "$@" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
r["cameras"][0]["model"]["fx"] = 1234.5
r["cameras"][0]["sensor"]["gain_e_per_dn"] = 9.9
r["projector"]["gamma"] = 2.9
r["lights"][0]["pos_mm"] = [1.0, 2.0, 3.0]
json.dump(r, open(sys.argv[2], "w"))
if len(sys.argv) > 3:
    r["cameras"][0]["name"] = "other"
    json.dump(r, open(sys.argv[3], "w"))
PY
}
