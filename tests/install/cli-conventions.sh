#!/bin/sh
# cli-conventions.sh BUILD: the conventions an operator expects of `impasto` and `impastod`
# (those of systemctl, git): --version; `impasto help [CMD]` prints what `impasto CMD --help`
# prints; a mistyped command gets "did you mean" and the usage exit code 2; wrong arguments
# say what was wrong; numbers are parsed strictly with the option named; one exit code per cause;
# process refuses unsafe places to write, shows progress lines when piped and writes previews. No daemon needed.
set -u
build=$1
imp=$build/cli/impasto impastod=$build/daemon/impastod
[ -x "$imp" ] || { echo "SKIP: $imp not built"; exit 77; }
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-conventions.XXXXXX") || exit 2
trap 'rm -rf "$tmp"' EXIT
failures=0
check() {   # check DESCRIPTION COMMAND...
  what=$1; shift
  if "$@"; then echo "ok: $what"; else echo "FAIL: $what"; failures=$((failures + 1)); fi
}
run() {     # run NAME ARGS...: stdout, stderr and the exit code into $tmp/NAME.{out,err,rc}
  name=$1; shift
  "$@" >"$tmp/$name.out" 2>"$tmp/$name.err"
  echo $? >"$tmp/$name.rc"
}
rc() { cat "$tmp/$1.rc"; }

run version "$imp" --version
check "impasto --version exits 0" [ "$(rc version)" = 0 ]
check "impasto --version prints 'impasto X.Y.Z'" grep -Eq '^impasto [0-9]+\.[0-9]+\.[0-9]+' "$tmp/version.out"
if [ -x "$impastod" ]; then
  run dversion "$impastod" --version
  check "impastod --version exits 0 (without a rig config)" [ "$(rc dversion)" = 0 ]
  check "impastod --version prints 'impastod X.Y.Z'" grep -Eq '^impastod [0-9]+\.[0-9]+\.[0-9]+' "$tmp/dversion.out"
  # a job's attempts are counted by impasto-worker, which refuses more than 100: impastod must
  # not accept a --job-attempts that would make every job it writes fail to load
  run dattempts timeout 20 "$impastod" --job-attempts 101 --socket "$tmp/no.sock"
  check "impastod --job-attempts 101: refused at start, naming the worker's bound, exit 2" \
    sh -c '[ "$(cat "$0")" = 2 ] && grep -qF -- "--job-attempts: expected an integer from 1 to 100, got \"101\"" "$1"' \
    "$tmp/dattempts.rc" "$tmp/dattempts.err"
fi

for cmd in scan jobs status process; do
  run help-$cmd "$imp" help $cmd
  run dash-$cmd "$imp" $cmd --help
  check "impasto help $cmd exits 0" [ "$(rc help-$cmd)" = 0 ]
  check "impasto help $cmd prints a usage" grep -q "usage: impasto $cmd" "$tmp/help-$cmd.out"
  check "impasto help $cmd = impasto $cmd --help" cmp -s "$tmp/help-$cmd.out" "$tmp/dash-$cmd.out"
done
run help "$imp" help
check "impasto help lists the commands (exit 0)" sh -c '[ "$(cat "$0")" = 0 ] && grep -q "^  scan " "$1"' \
  "$tmp/help.rc" "$tmp/help.out"

run scna "$imp" scna
check "impasto scna exits 2 (usage)" [ "$(rc scna)" = 2 ]
check "impasto scna suggests scan" grep -q "unknown command 'scna'; did you mean 'scan'?" "$tmp/scna.err"
run helpscna "$imp" help scna
check "impasto help scna suggests scan, exit 2" sh -c '[ "$(cat "$0")" = 2 ] && grep -q "did you mean '"'scan'"'" "$1"' \
  "$tmp/helpscna.rc" "$tmp/helpscna.err"
run zzz "$imp" frobnicate
check "a command with no near name: no suggestion, exit 2" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "unknown command '"'frobnicate'"'$" "$1"' "$tmp/zzz.rc" "$tmp/zzz.err"

# wrong arguments say what was wrong (no daemon is contacted: the socket does not exist)
sock=$tmp/none.sock
run jobsverb "$imp" jobs shwo --socket "$sock"
check "impasto jobs shwo: unknown action, did you mean show, exit 2" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "unknown action '"'shwo'"'; did you mean '"'show'"'" "$1"' \
  "$tmp/jobsverb.rc" "$tmp/jobsverb.err"
run jobsshow "$imp" jobs show --socket "$sock"
check "impasto jobs show (no id): says a JOB id is expected" grep -q "expected one JOB id, got 0" "$tmp/jobsshow.err"
run statusx "$imp" status extra --socket "$sock"
check "impasto status extra: names the unexpected argument, exit 2" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "unexpected argument '"'extra'"'" "$1"' "$tmp/statusx.rc" "$tmp/statusx.err"
# every command with actions: a mistyped action gets "did you mean", a missing word is named
while IFS='|' read -r args want; do
  # shellcheck disable=SC2086
  run words "$imp" $args --socket "$sock"
  check "impasto $args: exit 2, says: $want" sh -c '[ "$(cat "$0")" = 2 ] && grep -qF -- "$2" "$1"' \
    "$tmp/words.rc" "$tmp/words.err" "$want"
done <<'WORDS'
scan strat|impasto scan: unknown action 'strat'; did you mean 'start'?
scan show|impasto scan show: expected one SESSION id, got 0 words
scan|impasto scan: expected an action
plan estmate x|impasto plan: unknown action 'estmate'; did you mean 'estimate'?
plan estimate|impasto plan estimate: expected one PLAN, got 0 words
sim rendr|impasto sim: unknown action 'rendr'; did you mean 'render'?
queue frob|impasto queue: unknown action 'frob'
queue move|impasto queue move: expected an ID and a POSITION
calibrate camra|calibrate: unknown target 'camra'
bench accuracyy|impasto bench: unknown study 'accuracyy'
WORDS
run limit "$imp" jobs list --limit abc --socket "$sock"
check "impasto jobs --limit abc: refused naming the option, exit 2" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q -- "--limit: expected an integer from 1 to 1000, got '"'abc'"'" "$1"' \
  "$tmp/limit.rc" "$tmp/limit.err"
run pitch "$imp" process "$tmp" --out "$tmp/copy" --pitch abc
check "impasto process --pitch abc: refused naming the option, exit 2, nothing written" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q -- "--pitch: expected a number from 0 to 1000, got '"'abc'"'" "$1" && [ ! -e "$2" ]' \
  "$tmp/pitch.rc" "$tmp/pitch.err" "$tmp/copy"

# the same cause, the same exit code (core/exit-codes.h): a missing input is bad input, 3
run procnx "$imp" process "$tmp/nonexist" --out "$tmp/copy-nx"
run compnx "$imp" compare "$tmp/nonexist" --truth "$tmp/nonexist"
check "process and compare of a missing directory both exit 3 (bad input)" \
  sh -c '[ "$(cat "$0")" = 3 ] && [ "$(cat "$1")" = 3 ]' "$tmp/procnx.rc" "$tmp/compnx.rc"
check "process of a missing directory names it" grep -q "$tmp/nonexist: No such file or directory" "$tmp/procnx.err"

# process never writes into the capture set, nor over an existing copy without --force
mkdir -p "$tmp/cap/frames" "$tmp/old"
echo '{"format":"impasto-digital-copy"}' >"$tmp/old/copy.json"
run outin "$imp" process "$tmp/cap" --out "$tmp/cap/copy"
check "process CAP --out CAP/copy: refused, exit 2, nothing written" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "lies inside the capture set" "$1" && [ ! -e "$2" ]' \
  "$tmp/outin.rc" "$tmp/outin.err" "$tmp/cap/copy"
run outsame "$imp" process "$tmp/cap" --out "$tmp/cap/frames/../"
check "process CAP --out CAP (another spelling): refused, exit 2" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "lies inside the capture set" "$1"' "$tmp/outsame.rc" "$tmp/outsame.err"
run over "$imp" process "$tmp/cap" --out "$tmp/old"
check "process over an existing copy: refused naming --force, exit 2, copy untouched" \
  sh -c '[ "$(cat "$0")" = 2 ] && grep -q "holds a digital copy already; not overwritten (--force replaces it)" "$1" &&
         grep -q impasto-digital-copy "$2"' "$tmp/over.rc" "$tmp/over.err" "$tmp/old/copy.json"
run force "$imp" process "$tmp/cap" --out "$tmp/old" --force
check "with --force the copy's place is accepted (the empty set is then refused as bad input, 3)" \
  sh -c '[ "$(cat "$0")" = 3 ] && ! grep -q "not overwritten" "$1"' "$tmp/force.rc" "$tmp/force.err"

# plan estimate: the text says the processing time; --rig names what it wants
src=$(dirname "$0")/../..
run est "$imp" plan estimate "$src/config/plans/standard.cfg" --scene "$src/config/scenes/demo.cfg"
check "plan estimate: exit 0 and a processing line" sh -c '[ "$(cat "$0")" = 0 ] && grep -q "^processing " "$1"' \
  "$tmp/est.rc" "$tmp/est.out"
for preset in draft standard archival; do   # presets select lights by spread, not by the 48-light dome's ids
  run est-$preset "$imp" plan estimate "$src/config/plans/$preset.cfg" --scene "$src/config/scenes/small.cfg"
  check "plan estimate $preset.cfg on the 12-light small rig: exit 0" [ "$(rc est-$preset)" = 0 ]
  # the figures were measured on study-demo's 48-light dome: not promised for 12 lights
  check "plan estimate $preset.cfg on the 12-light rig: accuracy not measured for its 12-light dome, none promised" \
    sh -c 'grep -q "^expected accuracy  not measured for [0-9]* lights of a 12-light dome" "$0" && ! grep -q "^expected accuracy  height" "$0"' \
    "$tmp/est-$preset.out"
done
run est-study "$imp" plan estimate "$src/config/plans/standard.cfg" --scene "$src/config/scenes/study-demo.cfg"
check "plan estimate on the measured rig (study-demo) promises the measured figures" \
  grep -q "^expected accuracy  height RMSE" "$tmp/est-study.out"
run estrig "$imp" plan estimate "$src/config/plans/standard.cfg" --rig "$src/config/rigs/sim.cfg"
check "plan estimate --rig RIG.cfg: exit 3, says it wants rig.json" \
  sh -c '[ "$(cat "$0")" = 3 ] && grep -q "rig wants the rig.s model, rig.json" "$1"' "$tmp/estrig.rc" "$tmp/estrig.err"

# sim render: its counters are diagnostics on stderr, stdout holds the one result line
scene=$(dirname "$0")/../../config/scenes/small.cfg plan=$(dirname "$0")/../../config/plans/small.cfg   # with a dome: a BTF
if [ -f "$scene" ] && [ -f "$plan" ]; then
  run simr "$imp" sim render --scene "$scene" --plan "$plan" --out "$tmp/simset" --threads 1
  check "sim render: exit 0, one line on stdout, the counters on stderr" \
    sh -c '[ "$(cat "$0")" = 0 ] && [ "$(wc -l <"$1")" = 1 ] && ! grep -q counters: "$1" && grep -q "^counters: " "$2"' \
    "$tmp/simr.rc" "$tmp/simr.out" "$tmp/simr.err"
  # process, piped: one line per stage with the overall ETA, no carriage return; the previews
  run proc "$imp" process "$tmp/simset" --out "$tmp/simcopy" --threads 1
  check "process piped: exit 0, a line per stage with elapsed time and what is left, no carriage return" \
    sh -c '[ "$(cat "$0")" = 0 ] && grep -q "^process: hdr merge done in [0-9.]* s (25 % of the run, [0-9]* s elapsed" "$1" &&
           grep -q "^process: heightfield done in .* left)" "$1" && ! grep -q "$(printf "\r")" "$1"' \
    "$tmp/proc.rc" "$tmp/proc.err"
  pv=$tmp/simcopy/previews
  check "previews/index.html shows height, relief, sigma, flags, normals, colour by relative links that exist" \
    sh -c 'for f in height relief sigma flags normals albedo; do grep -q "src=\"$f.png\"" "$0/index.html" && [ -s "$0/$f.png" ] || exit 1; done' "$pv"
  check "height.png carries its colour bar: wider and taller than the copy's grid" python3 -c "
import json, struct, sys
w, h = struct.unpack('>II', open('$pv/height.png', 'rb').read()[16:24])
c = json.load(open('$tmp/simcopy/copy.json'))
sys.exit(not (w >= c['nx'] + 100 and h >= c['ny'] + 40))"
  # render without --fov frames the canvas (it filled about 10 % of the frame with a fixed 40°)
  run rend "$imp" render "$tmp/simcopy" --view 30,-25,70 --light -40,20,40 --size 400x300 --out "$tmp/relit.png"
  check "render frames the copy: at least 20 % of the 400x300 pixels see it" \
    sh -c '[ "$(cat "$0")" = 0 ] && [ "$(sed -n "s/.*: 400x300, \([0-9]*\) pixels see the copy.*/\1/p" "$1")" -ge 24000 ]' \
    "$tmp/rend.rc" "$tmp/rend.out"
  # on a terminal the BTF fit shows its progress in steps (it was one 0/1 step: jobs sat at 70 %)
  if command -v script >/dev/null 2>&1; then
    script -qc "'$imp' process '$tmp/simset' --out '$tmp/ttycopy' --threads 1" /dev/null >"$tmp/tty.out" 2>&1
    check "process on a terminal: the btf fit bar moves in at least 10 steps" \
      sh -c '[ "$(tr "\r" "\n" <"$0" | sed -n "s/^btf fit .* \([0-9]*\)\/[0-9]* .*/\1/p" | sort -u | wc -l)" -ge 10 ]' "$tmp/tty.out"
  fi
  # --force over the copy: built beside it and swapped in, nothing of the old copy survives
  echo stale >"$pv/../stale-from-the-old-copy.txt"
  run reproc "$imp" process "$tmp/simset" --out "$tmp/simcopy" --threads 1 --no-btf --force
  check "process --force over a copy: exit 0, no stale file, no BRDF map of the old copy (--no-btf), no leftovers" \
    sh -c '[ "$(cat "$0")" = 0 ] && [ -s "$1/copy.json" ] && [ ! -e "$1/stale-from-the-old-copy.txt" ] &&
           [ ! -e "$1/rho_d.exr" ] && [ -z "$(ls -d "$1".* 2>/dev/null)" ]' "$tmp/reproc.rc" "$tmp/simcopy"
  # without photometric frames: "no BTF possible", for a set planned without a dome and for an
  # aborted one that lost its dome sweep (refused, naming it)
  sed '/^dome = {/,/^};/d' "$(dirname "$plan")/quick.cfg" >"$tmp/nodome.cfg"
  "$imp" sim render --scene "$scene" --plan "$tmp/nodome.cfg" --out "$tmp/nodomeset" --threads 1 >/dev/null 2>&1
  run nodome "$imp" process "$tmp/nodomeset" --out "$tmp/nodomecopy" --threads 1 --quiet
  check "process of a set without dome frames: says no BTF possible" \
    sh -c '[ "$(cat "$0")" = 0 ] && grep -q "^no BTF possible: the capture set has no photometric (dome) frames" "$1"' \
    "$tmp/nodome.rc" "$tmp/nodome.out"
  # JSON: a figure that could not be measured is null, never -1 nor a 0 over no texels (the
  # copy without a dome has every texel flagged and none filled)
  run cmpnull "$imp" compare "$tmp/nodomecopy" --truth "$tmp/nodomeset/truth" --json
  check "compare --json: no -1, and the figures over no texels are null" python3 -c "
import json, sys
j = json.load(open('$tmp/cmpnull.out'))
def walk(x):
    if isinstance(x, dict):
        for v in x.values(): yield from walk(v)
    elif isinstance(x, list):
        for v in x: yield from walk(v)
    else: yield x
assert j['n_unflagged'] == 0 and j['n_filled'] == 0, (j['n_unflagged'], j['n_filled'])
sys.exit(any(v == -1 for v in walk(j) if isinstance(v, (int, float)) and not isinstance(v, bool)) or
         any(j[k] is not None for k in ('beyond_3sigma_height', 'beyond_3sigma_normal', 'unflagged_normal_err_deg_max',
                                        'height_rmse_um_filled', 'normal_err_deg_mean_filled')))"
  "$imp" sim render --scene "$scene" --plan "$(dirname "$plan")/quick.cfg" --out "$tmp/abortset" --threads 1 >/dev/null 2>&1
  grep -v -e '"step":"dome"' -e '"step":"dark"' "$tmp/abortset/manifest.jsonl" >"$tmp/m" && mv "$tmp/m" "$tmp/abortset/manifest.jsonl"
  run abort "$imp" process "$tmp/abortset" --out "$tmp/abortcopy" --threads 1 --quiet
  check "process of a set aborted before its dome sweep: refused (3), naming the missing dome frames and no BTF" \
    sh -c '[ "$(cat "$0")" = 3 ] && grep -q "dome: 3 of 3 frames (lights 0, 3, 6): no photometric frame, so no BTF possible" "$1"' \
    "$tmp/abort.rc" "$tmp/abort.err"
fi

[ $failures -eq 0 ] || { echo "$failures failed"; exit 1; }
echo "conventions verified"
