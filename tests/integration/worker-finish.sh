#!/bin/bash
# impasto-worker --batch DIR --finish, the step after every task of a batch (docs/scale-out.md),
# without Slurm (the tasks run by hand): on a batch whose captures are the two tiles of a
# rendered painting (tests/data/worker-painting*.cfg) it runs `impasto mosaic` over the batch's
# copies into DIR/mosaic, the same files as `impasto mosaic` run by hand on the painting, and
# records it in DIR/result.json; tiles processed at different pitches make the mosaic fail,
# and the batch with it (exit 1, state failed, no DIR/mosaic, `impasto jobs list --slurm`
# shows why); a one-capture batch records
# "nothing to mosaic".
# Usage: worker-finish.sh BUILD_DIR SOURCE_DIR
set -u
bin=$(cd "$1" && pwd) src=$(cd "$2" && pwd)
NAME=worker-finish
. "$src/tests/integration/lib-check.sh"
worker=$bin/cli/impasto-worker
P=$tmp/painting
"$imp" sim render --scene "$src/tests/data/worker-painting.cfg" --plan "$src/tests/data/worker-painting-plan.cfg" \
  --out "$P" --quiet --threads 2 >"$tmp/render.log" 2>&1 || { cat "$tmp/render.log"; echo "FAIL render"; exit 1; }
# batch NAME WORKER_ARGS COPIES_DIR TILE...: DIR/batch.json (the format of pipeline/model/batch.h)
batch() {
  mkdir -p "$tmp/$1"
  python3 - "$tmp/$1/batch.json" "$2" "$3" "$P" "${@:4}" <<'PY'
import json, sys
out, args, copies, p, tiles = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5:]
json.dump({"format": 1, "id": out.split("/")[-2], "created": "2026-11-26T23:00:00Z", "worker_args": args or None,
           "engine": "slurm", "submissions": [],
           "tasks": [{"capture": f"{p}/tiles/{t}", "copy": f"{copies}/{t}"} for t in tiles]}, open(out, "w"))
PY
}
mosaic_field() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["mosaic"].get(sys.argv[2], ""))' "$@"; }

# the painting: both tiles at one pitch, the copies where painting.json says (copies/NNNN)
batch paint "--pitch 0.2" "$P/copies" 0000 0001
for t in 0 1; do
  "$worker" --batch "$tmp/paint" --task $t >"$tmp/task$t.log" 2>&1 || { cat "$tmp/task$t.log"; echo "FAIL task $t"; exit 1; }
done
"$worker" --batch "$tmp/paint" --finish >"$tmp/finish.log" 2>&1
check "the finish step of a painting exits 0" [ $? -eq 0 ]
check "it ran impasto mosaic" grep -q "^seam step: " "$tmp/finish.log"
check "result.json: the batch is done" grep -q '"state": "done"' "$tmp/paint/result.json"
check "result.json: the mosaic is done, of 2 tiles, in DIR/mosaic" \
  [ "$(mosaic_field "$tmp/paint/result.json" state)/$(mosaic_field "$tmp/paint/result.json" tiles)/$(mosaic_field "$tmp/paint/result.json" copy)" = "done/2/$tmp/paint/mosaic" ]
check "DIR/mosaic holds a mosaic" [ -s "$tmp/paint/mosaic/mosaic.json" ] && [ ! -e "$tmp/paint/mosaic.partial" ]
"$imp" mosaic "$P" --out "$tmp/ref-mosaic" >"$tmp/ref.log" 2>&1 || { cat "$tmp/ref.log"; echo "FAIL reference mosaic"; exit 1; }
check "it equals impasto mosaic of the painting, file for file" diff -r "$tmp/ref-mosaic" "$tmp/paint/mosaic"

# one capture (tile 0001 at the pitch it picks itself): nothing to mosaic
batch one "" "$tmp/auto" 0001
"$worker" --batch "$tmp/one" --task 0 >"$tmp/one.log" 2>&1 || { cat "$tmp/one.log"; echo "FAIL task"; exit 1; }
"$worker" --batch "$tmp/one" --finish >"$tmp/one-finish.log" 2>&1
check "a one-capture batch finishes (exit 0)" [ $? -eq 0 ]
check "... recording nothing to mosaic" bash -c "[ \"\$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))[\"mosaic\"][\"reason\"])' $tmp/one/result.json)\" = 'nothing to mosaic: one capture' ]"
check "... and runs no mosaic" [ ! -e "$tmp/one/mosaic" ]

# tiles at different pitches (0000 at 0.2 mm, 0001 at its own): the mosaic refuses them, and
# the batch fails (both copies are done: only the finish step runs)
batch pitches "" "$tmp/unused" 0000 0001
python3 - "$tmp/pitches/batch.json" "$P/copies/0000" "$tmp/auto/0001" <<'PY'
import json, sys
b = json.load(open(sys.argv[1]))
b["tasks"][0]["copy"], b["tasks"][1]["copy"] = sys.argv[2], sys.argv[3]
json.dump(b, open(sys.argv[1], "w"))
PY
"$worker" --batch "$tmp/pitches" --finish >"$tmp/pfinish.log" 2>&1
check "a failed mosaic fails the finish step (exit 1)" [ $? -eq 1 ]
check "... naming the two pitches" grep -q "pitch_mm .* differs from the first tile's" "$tmp/pfinish.log"
check "... with state failed and the reason" bash -c "grep -q '\"state\": \"failed\"' $tmp/pitches/result.json && \
  [ \"\$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))[\"mosaic\"][\"state\"])' $tmp/pitches/result.json)\" = failed ]"
check "... and publishes no mosaic" [ ! -e "$tmp/pitches/mosaic" ]
"$imp" jobs list --slurm "$tmp/pitches" >"$tmp/plist.txt" 2>&1
check "jobs list --slurm shows the finish step failed with the mosaic's error" \
  grep -q "^finish *failed .*the mosaic failed: impasto mosaic exited with status" "$tmp/plist.txt"
finish
