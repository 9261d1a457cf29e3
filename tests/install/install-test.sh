#!/bin/sh
# install-test.sh SRC BUILD: what an operator gets from `cmake --install`. Installs BUILD with
# prefix /usr/local into a DESTDIR and checks that the installed units name what was
# installed (ExecStart binary, --rig config, plan dir, worker, Documentation=), that
# tmpfiles creates the folders impastod writes, that impastod's compiled-in defaults follow
# the prefix, and `systemd-analyze verify` on the installed units. Then starts the installed
# impastod exactly as impastod.service does (paths moved into the DESTDIR, state in a temp
# dir) in front of the emulated rig served by the installed `impasto sim serve`, and checks
# that the installed `impasto status` answers with the rig and its calibration loaded, and
# that installing again keeps an edited rig config. With a third argument `night`, then the
# queued night of tests/install/night.sh.
# Runs itself in a private network namespace (the emulator listens on fixed loopback
# ports); exit 77 (skipped) when impastod is not built or no namespace can be made.
set -u
src=$1 build=$2 mode=${3:-}
prefix=/usr/local
[ -x "$build/daemon/impastod" ] && [ -x "$build/cli/impasto" ] && [ -x "$build/cli/impasto-worker" ] ||
  { echo "SKIP: impastod, impasto or impasto-worker not built"; exit 77; }
if [ -z "${IMPASTO_INSTALL_NETNS:-}" ]; then
  IMPASTO_INSTALL_NETNS=1 exec unshare -n sh -c 'ip link set lo up && exec sh "$0" "$@"' "$0" "$@" ||
    { echo "SKIP: no private network namespace (unshare -n)"; exit 77; }
fi

failures=0 serve_pid="" daemon_pid=""
tmp=$(mktemp -d "${TMPDIR:-/tmp}/impasto-install.XXXXXX") || exit 2
cleanup() {    # KEEP_TMP=1 keeps the folder of a passing run too (to compare with a failing one)
  for p in $daemon_pid $serve_pid; do kill -TERM "$p" 2>/dev/null; wait "$p" 2>/dev/null; done
  if [ $failures -eq 0 ] && [ -z "${KEEP_TMP:-}" ]; then rm -rf "$tmp"; else echo "kept $tmp"; fi
}
trap cleanup EXIT
trap 'exit 143' TERM INT
check() {   # check DESCRIPTION COMMAND...
  what=$1; shift
  if "$@"; then echo "ok: $what"; else echo "FAIL: $what"; failures=$((failures + 1)); fi
}

root=$tmp/root
DESTDIR=$root cmake --install "$build" --prefix "$prefix" >"$tmp/install.log" 2>&1 ||
  { cat "$tmp/install.log"; echo "FAIL: cmake --install"; exit 1; }
units=$root$prefix/lib/systemd/system
svc=$units/impastod.service
for u in impastod.service impastod.socket impasto-worker@.service; do
  check "$u installed" test -f "$units/$u"
done
[ -f "$svc" ] || exit 1

# ExecStart= of impastod.service, word by word: the binary and --config; the settings are
# in the installed impastod.conf.
exec_words=$(sed -n 's/^ExecStart=//p' "$svc")
opt_value() {   # opt_value OPTION: the word after OPTION in ExecStart= (first one)
  printf '%s\n' $exec_words | awk -v o="$1" 'prev == o { print; exit } { prev = $0 }'
}
bin=$(printf '%s\n' $exec_words | head -n1)
conf=$(opt_value --config)
check "ExecStart binary $bin is installed and executable" test -x "$root$bin"
check "ExecStart passes --config (the settings, the rig config among them)" test -n "$conf"
check "the --config file $conf is installed" test -f "$root$conf"
conf_value() {  # conf_value NAME: the string value of NAME = "…"; in impastod.conf
  sed -n 's/^ *'"$1"' *= *"\([^"]*\)";.*/\1/p' "$root$conf" | head -n1
}
rig=$(conf_value rig) worker=$(conf_value worker) calib=$(conf_value calibrate_cmd)
check "impastod.conf names a rig config (impastod cannot start without one)" test -n "$rig"
check "the rig config $rig is installed" test -f "$root$rig"
check "the worker $worker is installed and executable" test -n "$worker" -a -x "$root$worker" -a ! -d "$root$worker"
check "the calibrate_cmd $calib is installed and executable" test -n "$calib" -a -x "$root$calib" -a ! -d "$root$calib"
for pd in $(sed -n 's/^ *plan_dirs *= *\[\(.*\)\];.*/\1/p' "$root$conf" | tr -d '",'); do
  case $pd in /var/lib/impasto/*) ;;   # made by tmpfiles/StateDirectory=
  *) check "plan dir $pd is installed (impastod refuses a missing one)" test -d "$root$pd" ;; esac
done
wbin=$(sed -n 's/^ExecStart=\([^ ]*\).*/\1/p' "$units/impasto-worker@.service")
check "impasto-worker@.service runs an installed binary ($wbin)" test -x "$root$wbin"
for u in impastod.service impastod.socket impasto-worker@.service; do
  for doc in $(sed -n 's/^Documentation=//p' "$units/$u"); do
    case $doc in
    file://*) check "$u: Documentation=$doc is installed" test -f "$root${doc#file://}" ;;
    man:*) check "$u: Documentation=$doc is installed" \
      sh -c 'ls "$0"'"$prefix"'/share/man/man*/"$1".* >/dev/null 2>&1' "$root" "$(echo "${doc#man:}" | sed 's/(.*//')" ;;
    esac
  done
done

# tmpfiles: every folder impastod writes below its state dir
tmpf=$root$prefix/lib/tmpfiles.d/impasto.conf
for dir in sessions jobs outputs calibrations; do
  check "tmpfiles creates /var/lib/impasto/$dir" grep -Eq "^d /var/lib/impasto/$dir( |$)" "$tmpf"
done
check "the sysusers snippet is installed" test -f "$root$prefix/lib/sysusers.d/impasto.conf"

# compiled-in defaults follow the prefix
help=$("$root$prefix/sbin/impastod" --help)
check "impastod's default worker is $prefix/bin/impasto-worker" \
  sh -c 'printf "%s\n" "$0" | grep -q "default '"$prefix"'/bin/impasto-worker)"' "$help"
check "impastod's default rig config is the installed one ($rig)" \
  sh -c 'printf "%s\n" "$0" | grep -qF "default '"$rig"')"' "$help"

# systemd-analyze verify on the installed units, with the DESTDIR binaries
sh "$src/tests/systemd-verify.sh" "$units" "$root$bin" "$root$wbin" \
  "$root$prefix/lib/sysusers.d/impasto.conf" "$tmpf" >"$tmp/verify.log" 2>&1
rc=$?
case $rc in
0) echo "ok: systemd-analyze verify on the installed units" ;;
77) echo "note: $(tail -n1 "$tmp/verify.log")" ;;
*) cat "$tmp/verify.log"; echo "FAIL: systemd-analyze verify on the installed units"; failures=$((failures + 1)) ;;
esac

[ -n "$rig" ] && [ -f "$root$rig" ] || { echo "$failures failed (no rig config to start impastod with)"; exit 1; }

# The emulated rig behind the installed rig config (its devices on 127.0.0.1, Modbus 15020);
# rig.json, which the config names, written next to it as an operator's calibration would be.
cfgdir=$(dirname "$rig")
"$root$prefix/bin/impasto" sim serve --scene "$src/config/scenes/small.cfg" --address 127.0.0.1 \
  --rig-out "$root$cfgdir/rig.json" --ready-file "$tmp/ready" >"$tmp/serve.log" 2>&1 &
serve_pid=$!
for _ in $(seq 600); do [ -s "$tmp/ready" ] || ! kill -0 $serve_pid 2>/dev/null && break; sleep 0.1; done
[ -s "$tmp/ready" ] || { cat "$tmp/serve.log"; echo "FAIL: impasto sim serve did not start"; exit 1; }
proj=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["projector"]["name"])' "$root$cfgdir/rig.json")
sed -i "s|name = \"proj0\"|name = \"$proj\"|" "$root$rig"

# impastod as the unit starts it, with the installed config: its paths moved into the
# DESTDIR, state in $tmp.
mkdir -p "$tmp/state"
sed -e 's|"'"$prefix"'/|"'"$root$prefix"'/|g' -e 's|"/var/lib/impasto|"'"$tmp/state"'|g' "$root$conf" >"$tmp/impastod.conf"
set -- "$root$bin" --config "$tmp/impastod.conf"
sock=$tmp/control.sock
"$@" --socket "$sock" --operators-all >"$tmp/impastod.log" 2>&1 &
daemon_pid=$!
for _ in $(seq 150); do
  "$root$prefix/bin/impasto" status --socket "$sock" --json >"$tmp/status.json" 2>/dev/null && break
  kill -0 $daemon_pid 2>/dev/null || break
  sleep 0.1
done
check "the installed impastod answers the installed impasto status" grep -q '"simulated"' "$tmp/status.json"
check "impastod loaded the rig calibration" sh -c '! grep -q "rig calibration" "$0"' "$tmp/impastod.log"
check "impastod found its worker" sh -c '! grep -q "every processing job will fail" "$0"' "$tmp/impastod.log"
kill -TERM $daemon_pid; wait $daemon_pid; rc=$?; daemon_pid=""
check "impastod stops with exit 0 on SIGTERM" [ $rc -eq 0 ]

# A worker that is not there is said at start, not found by three failed jobs.
"$root$bin" --rig "$root$rig" --state-dir "$tmp/state2" --socket "$tmp/s2.sock" \
  --worker-cmd "$tmp/no-such-worker" >"$tmp/impastod2.log" 2>&1 &
daemon_pid=$!
for _ in $(seq 150); do [ -S "$tmp/s2.sock" ] && break; sleep 0.1; done
kill -TERM $daemon_pid; wait $daemon_pid; daemon_pid=""
check "a missing worker is reported at start" grep -q "no-such-worker: .*every processing job will fail" "$tmp/impastod2.log"

# Installing again (an upgrade) keeps the operator's rig config.
echo "# edited by the operator" >>"$root$rig"
DESTDIR=$root cmake --install "$build" --prefix "$prefix" >"$tmp/install2.log" 2>&1
check "a second install keeps an edited rig config" grep -q "^# edited by the operator" "$root$rig"

[ "$mode" = night ] && . "$src/tests/install/night.sh"

[ $failures -eq 0 ] || { echo "--- impastod.log"; cat "$tmp/impastod.log"; echo "$failures failed"; exit 1; }
echo "install verified"
