#!/bin/sh
# man-completion.sh BUILD: the generated man pages render without a warning (man -l, and
# groff -ww for every warning) and carry what they are generated from (impasto(1) lists every
# command of `impasto help`, impastod(8) the options of `impastod --help`); the generated
# bash completion completes `impasto sc<TAB>` to scan and `impasto process --<TAB>` to its flags.
set -u
build=$1
imp=$build/cli/impasto
[ -x "$imp" ] || { echo "SKIP: $imp not built"; exit 77; }
if [ ! -d "$build/man" ] && ! grep -q '^IMPASTO_PYTHON3:FILEPATH=/' "$build/CMakeCache.txt"; then
  echo "SKIP: no python3 at configure time: man pages and completion not generated"; exit 77
fi
command -v man >/dev/null && command -v groff >/dev/null || { echo "SKIP: man or groff missing"; exit 77; }
command -v bash >/dev/null || { echo "SKIP: no bash"; exit 77; }
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-man.XXXXXX") || exit 2
trap 'rm -rf "$tmp"' EXIT
failures=0
check() {   # check DESCRIPTION COMMAND...
  what=$1; shift
  if "$@"; then echo "ok: $what"; else echo "FAIL: $what"; failures=$((failures + 1)); fi
}

for page in impasto.1 impastod.8 impastod.conf.5 impasto-capture-set.5 impasto-copy.5; do
  f=$build/man/$page
  check "$page generated" [ -s "$f" ]
  [ -s "$f" ] || continue
  LC_ALL=C.UTF-8 MANWIDTH=80 MAN_KEEP_FORMATTING= man --warnings=all -E UTF-8 -l "$f" \
    >"$tmp/$page.txt" 2>"$tmp/$page.err"
  rc=$?
  groff -k -man -ww -z -Tutf8 "$f" 2>>"$tmp/$page.err"   # every groff warning (man -l shows few)
  check "$page: man -l and groff -ww render it without warnings" sh -c '[ "$1" = 0 ] && [ ! -s "$0" ]' \
    "$tmp/$page.err" "$rc"
  [ -s "$tmp/$page.err" ] && sed 's/^/  /' "$tmp/$page.err"
  check "$page: has NAME and SEE ALSO" sh -c 'grep -q "^NAME" "$0" && grep -q "^SEE ALSO" "$0"' "$tmp/$page.txt"
done
# impasto(1)'s command list is the program's: every command of `impasto help` is in it
"$imp" help | sed -n '/^commands:/,/^$/s/^  \([a-z_-]*\) .*/\1/p' >"$tmp/cmds"
check "impasto help lists commands" [ -s "$tmp/cmds" ]
missing=$(while read -r c; do grep -Eq "^ {7}$c( |\$)" "$tmp/impasto.1.txt" || echo "$c"; done <"$tmp/cmds")
check "impasto(1) lists every command of impasto help (missing: ${missing:-none})" [ -z "$missing" ]
if [ -x "$build/daemon/impastod" ]; then
  check "impastod(8) carries impastod --help's options" grep -q -- "--state-dir DIR" "$tmp/impastod.8.txt"
fi

comp=$build/completion/impasto
check "bash completion generated" [ -s "$comp" ]
complete_words() {   # complete_words WORD... : what <TAB> offers after them (the last is the one completed)
  bash -c '. "$0"; shift 0; COMP_WORDS=("$@"); COMP_CWORD=$(($# - 1)); _impasto; printf "%s\n" "${COMPREPLY[@]}"' \
    "$comp" "$@" 2>&1
}
check "impasto sc<TAB> completes to scan" [ "$(complete_words impasto sc)" = scan ]
complete_words impasto process -- >"$tmp/process-flags"
for f in --out --force --allow-incomplete --pitch --quiet; do
  check "impasto process --<TAB> offers $f" grep -qx -- "$f" "$tmp/process-flags"
done
check "impasto process --<TAB> offers no flag of another command (--truth)" sh -c '! grep -qx -- --truth "$0"' \
  "$tmp/process-flags"
check "impasto plan <TAB> offers validate and estimate" \
  sh -c '[ "$(echo $(bash -c ". \"\$0\"; COMP_WORDS=(impasto plan \"\"); COMP_CWORD=2; _impasto; printf \"%s \" \"\${COMPREPLY[@]}\"" "$0"))" = "validate estimate" ]' "$comp"
check "impasto help sc<TAB> completes to scan" [ "$(complete_words impasto help sc)" = scan ]

[ $failures -eq 0 ] || { echo "$failures failed"; exit 1; }
echo "man pages and completion verified"
