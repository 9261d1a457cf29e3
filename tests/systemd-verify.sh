#!/bin/sh
# systemd-verify.sh UNIT_DIR IMPASTOD IMPASTO_WORKER [SYSUSERS TMPFILES]: runs
# `systemd-analyze verify` on impasto's units (as configured into the build tree, or as
# installed) and fails on any message that names one of them. The units point at the
# installed impastod and impasto-worker, which may not exist yet, so a temporary copy has
# the ExecStart= binary rewritten to the given ones (any executable stands in when a binary
# is not built: verify only checks that it exists). SYSUSERS/TMPFILES default to
# UNIT_DIR/impasto.sysusers and UNIT_DIR/impasto.tmpfiles. Messages about
# other units of the host (its own broken units, missing man pages) are ignored.
# Exit 77 (skipped) without systemd-analyze.
set -u
src=$1 impastod=$2 worker=$3
sysusers=${4:-$src/impasto.sysusers} tmpfiles=${5:-$src/impasto.tmpfiles}
command -v systemd-analyze >/dev/null 2>&1 || { echo "SKIP: systemd-analyze not found"; exit 77; }
[ -x "$impastod" ] || impastod=/bin/true
[ -x "$worker" ] || worker=/bin/true
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-units-XXXXXX") || exit 2
trap 'rm -rf "$tmp"' EXIT INT TERM
units="impastod.service impastod.socket impasto-worker@.service"
for u in $units; do
        [ -f "$src/$u" ] || { echo "FAIL: $src/$u missing"; exit 1; }
        sed -e "s|^ExecStart=[^ ]*/impastod |ExecStart=$impastod |" \
            -e "s|^ExecStart=[^ ]*/impasto-worker |ExecStart=$worker |" "$src/$u" >"$tmp/$u" || exit 2
done
# a template is verified through an instance
cp "$tmp/impasto-worker@.service" "$tmp/impasto-worker@1.service"
# sysusers and tmpfiles: each line must parse (systemd-sysusers/tmpfiles --dry-run where available)
fail=0
if command -v systemd-sysusers >/dev/null 2>&1; then
        out=$(systemd-sysusers --dry-run "$sysusers" 2>&1 | grep -E "$(basename "$sysusers"):[0-9]+")
        [ -z "$out" ] || { echo "FAIL sysusers: $out"; fail=1; }
fi
if command -v systemd-tmpfiles >/dev/null 2>&1; then
        out=$(systemd-tmpfiles --dry-run --create "$tmpfiles" 2>&1 | grep -Ei "$(basename "$tmpfiles"):[0-9]+")
        # "--dry-run" appeared in systemd 253; an older tool says so and the check is skipped
        case "$out" in *"unrecognized option"*|"") ;; *) echo "FAIL tmpfiles: $out"; fail=1 ;; esac
fi
out=$(cd "$tmp" && SYSTEMD_LOG_LEVEL=notice systemd-analyze verify --man=no \
        "$tmp/impastod.socket" "$tmp/impastod.service" "$tmp/impasto-worker@1.service" 2>&1)
rc=$?
echo "$out"
# lines about our units: the temp dir, or the unit names
ours=$(printf '%s\n' "$out" | grep -E "$tmp|impastod\.(service|socket)|impasto-worker@" || true)
if [ -n "$ours" ]; then
        echo "FAIL: systemd-analyze verify has something to say about impasto's units:"
        printf '%s\n' "$ours"
        fail=1
elif [ $rc -ne 0 ]; then
        echo "note: systemd-analyze verify exited $rc for reasons outside impasto's units, ignoring"
fi
[ $fail -eq 0 ] && echo "impasto units verified"
exit $fail
