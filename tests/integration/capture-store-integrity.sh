#!/bin/bash
# Readers never change a capture set, and never accept a wrong one (docs/capture-set.md,
# "What readers guarantee"): on a small simulated set (config/scenes/small.cfg with
# config/plans/small.cfg, 54 frames) —
#  - one flipped bit in a manifest `file` value: process refuses naming line and field, and
#    the set is byte-identical afterwards (it used to delete the good frame as an orphan);
#  - a damaged last manifest line: process refuses, the set is unchanged (it used to cut the
#    line, delete its frame and exit 0); `impasto repair --dry-run` changes nothing, `impasto
#    repair` moves the line's bytes and the frame into quarantine/ (nothing deleted);
#  - `"light":3` → `7` in the manifest (caught against plan.cfg), `"bit":3` → `7` without
#    plan.cfg and two frames swapped on disk with their checksums (caught by each frame's
#    embedded record): process refuses naming the frame and the field;
#  - a set with 1 of 12 dome lights, or none: process refuses (exit 3) naming what is missing,
#    the set unchanged; --allow-incomplete processes it and copy.json says what was missing.
# Usage: capture-store-integrity.sh BUILD_DIR SOURCE_DIR
set -u
bin=$1 src=$2
NAME=store-integrity
. "$src/tests/integration/lib-check.sh"

"$imp" sim render --scene "$src/config/scenes/small.cfg" --plan "$src/config/plans/small.cfg" \
  --out "$tmp/base" --quiet >"$tmp/render.log" 2>&1 || { cat "$tmp/render.log"; echo "FAIL sim render"; exit 1; }
rm -rf "$tmp/base/truth"

# tree_hash DIR: names, sizes and contents of everything in DIR
tree_hash() { (cd "$1" && find . -print0 | sort -z | xargs -0 stat -c '%n %s %F' && find . -type f -print0 | sort -z | xargs -0 sha256sum) | sha256sum; }
fresh() { rm -rf "$tmp/$1" "$tmp/$1.copy"; cp -a "$tmp/base" "$tmp/$1"; }
# flip LINE OLD NEW SET: replaces the first OLD by NEW on manifest line LINE (one character)
flip() { python3 - "$@" <<'PY'
import sys
line, old, new, d = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
p = d + "/manifest.jsonl"
ls = open(p, "rb").read().split(b"\n")
assert old.encode() in ls[line - 1], (line, old)
ls[line - 1] = ls[line - 1].replace(old.encode(), new.encode(), 1)
open(p, "wb").write(b"\n".join(ls))
PY
}
# process SET [ARGS]: exit code in $rc, messages in $tmp/err
process() { local s=$1; shift; "$imp" process "$tmp/$s" --out "$tmp/$s.copy" --quiet --no-btf "$@" >/dev/null 2>"$tmp/err"; rc=$?; }
refused() { [ "$rc" -ne 0 ] && grep -q -- "$1" "$tmp/err" || { echo "  exit $rc: $(cat "$tmp/err")"; false; }; }

# --- item: a flipped bit in a `file` value ('2' ^ 1 = '3')
fresh s1
flip 3 '"frames/000002.tiff"' '"frames/000003.tiff"' "$tmp/s1"
before=$(tree_hash "$tmp/s1")
process s1
check "flipped file value: process refuses naming line 3 and the field" refused 'manifest.jsonl:3: file: expected "frames/000002.tiff"'
check "flipped file value: the set is unchanged" [ "$(tree_hash "$tmp/s1")" = "$before" ]
check "flipped file value: the good frame is still there" [ -f "$tmp/s1/frames/000002.tiff" ]
"$imp" repair "$tmp/s1" >/dev/null 2>&1; rc=$?
check "flipped file value: repair refuses (not a crash's damage) and moves nothing" \
  sh -c "[ $rc -eq 3 ] && [ '$(tree_hash "$tmp/s1")' = '$before' ]"

# --- item: a damaged last line ('{' ^ 1 = 'z')
fresh s2
python3 - "$tmp/s2/manifest.jsonl" <<'PY'
import sys
p = sys.argv[1]
b = bytearray(open(p, "rb").read())
b[b.rindex(b"\n", 0, len(b) - 1) + 1] ^= 1
open(p, "wb").write(bytes(b))
PY
cp "$tmp/s2/manifest.jsonl" "$tmp/s2-manifest.orig"
before=$(tree_hash "$tmp/s2")
process s2
check "damaged last line: process refuses naming line 54" refused 'manifest.jsonl:54: the last line is unreadable'
check "damaged last line: the set is unchanged" [ "$(tree_hash "$tmp/s2")" = "$before" ]
"$imp" repair "$tmp/s2" --dry-run >"$tmp/dry" 2>&1; rc=$?
check "repair --dry-run lists the line and the frame and changes nothing" \
  sh -c "[ $rc -eq 0 ] && grep -q 'manifest.jsonl:54' '$tmp/dry' && grep -q 'frames/000053.tiff' '$tmp/dry' && [ '$(tree_hash "$tmp/s2")' = '$before' ]"
"$imp" repair "$tmp/s2" >"$tmp/rep" 2>&1; rc=$?
check "repair moves the line and the frame into quarantine/" \
  sh -c "[ $rc -eq 0 ] && grep -q '2 items moved' '$tmp/rep' && [ -f '$tmp/s2/quarantine/000053.tiff' ] && [ ! -e '$tmp/s2/frames/000053.tiff' ]"
check "repair deleted nothing: manifest + quarantined tail = the original manifest" \
  sh -c "cat '$tmp/s2/manifest.jsonl' '$tmp/s2/quarantine/manifest-tail.jsonl' | cmp -s - '$tmp/s2-manifest.orig' && cmp -s '$tmp/s2/quarantine/000053.tiff' '$tmp/base/frames/000053.tiff'"

# --- item: the manifest cross-checked against each frame's embedded record
light3=$(grep -n '"step":"dome".*"light":3,' "$tmp/base/manifest.jsonl" | head -1 | cut -d: -f1)
fresh s3
flip "$light3" '"light":3,' '"light":7,' "$tmp/s3"
before=$(tree_hash "$tmp/s3")
process s3
check "light 3 -> 7 (with plan.cfg): refused naming the frame and the field" refused "manifest.jsonl:$light3 (frames/$(printf %06d $((light3 - 1))).tiff): light"
check "light 3 -> 7: the set is unchanged" [ "$(tree_hash "$tmp/s3")" = "$before" ]
# without plan.cfg the frame's embedded record is what catches it (a Gray frame: loaded first)
bit3=$(grep -n '"kind":"gray","axis":"x","bit":3,' "$tmp/base/manifest.jsonl" | head -1 | cut -d: -f1)
fresh s3b
flip "$bit3" '"bit":3,' '"bit":7,' "$tmp/s3b"
rm "$tmp/s3b/plan.cfg"
before=$(tree_hash "$tmp/s3b")
process s3b
check "Gray bit 3 -> 7 (no plan.cfg): refused by the embedded record, naming frame and field" \
  refused "frames/$(printf %06d $((bit3 - 1))).tiff: pattern.bit: manifest.jsonl:$bit3 says {.*\"bit\":7"
check "Gray bit 3 -> 7: the set is unchanged" [ "$(tree_hash "$tmp/s3b")" = "$before" ]

fresh s4
python3 - "$tmp/s4" "$bit3" <<'PY'
import json, os, sys
d, a = sys.argv[1], int(sys.argv[2]) - 1          # swap frames a and a+1 with their checksums
p = d + "/manifest.jsonl"
ls = [json.loads(l) for l in open(p)]
fa, fb = d + "/" + ls[a]["file"], d + "/" + ls[a + 1]["file"]
os.rename(fa, fa + ".x"); os.rename(fb, fa); os.rename(fa + ".x", fb)
for k in ("crc32", "size_bytes"):
    ls[a][k], ls[a + 1][k] = ls[a + 1][k], ls[a][k]
with open(p, "w") as f:
    for r in ls:
        f.write(json.dumps(r, separators=(",", ":")) + "\n")
PY
process s4
check "two frames swapped with their checksums: refused naming the frame" refused "frames/$(printf %06d $((bit3 - 1))).tiff: seq: manifest.jsonl:$bit3 says $((bit3 - 1)), the frame's embedded record says $bit3"

# --- item: incomplete sets (1 of 12 dome lights; none)
first_dome=$(grep -n '"step":"dome"' "$tmp/base/manifest.jsonl" | head -1 | cut -d: -f1)
for keep in 1 0; do
  s=inc$keep
  fresh $s
  n=$((first_dome - 1 + keep))
  head -n $n "$tmp/base/manifest.jsonl" >"$tmp/$s/manifest.jsonl"
  for f in "$tmp/$s"/frames/*.tiff; do i=$((10#$(basename "$f" .tiff))); [ $i -ge $n ] && rm "$f"; done
  before=$(tree_hash "$tmp/$s")
  process $s
  check "$keep of 12 dome lights: refused (exit 3) naming what is missing" \
    sh -c "[ $rc -eq 3 ] && grep -q 'incomplete: $((12 - keep)) of the plan.s 54 frames are missing (dome: $((12 - keep)) of 12 frames' '$tmp/err'"
  check "$keep of 12 dome lights: the set is unchanged" [ "$(tree_hash "$tmp/$s")" = "$before" ]
done
process inc1 --allow-incomplete
check "--allow-incomplete processes it" [ "$rc" -eq 0 ]
check "copy.json provenance.incomplete says 11 dome frames are missing" python3 -c "
import json, sys
m = json.load(open('$tmp/inc1.copy/copy.json'))['provenance']['incomplete']
sys.exit(not (m['frames_missing'] == 11 and m['steps']['dome']['missing'] == 11 and len(m['steps']['dome']['lights']) == 11))"
finish
