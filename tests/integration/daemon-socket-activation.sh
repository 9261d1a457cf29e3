#!/bin/bash
# impastod under socket activation, started the way systemd starts it from
# impastod.socket: `systemd-socket-activate` binds and listens on the socket, and on the first
# connection execs impastod with LISTEN_FDS=1, LISTEN_PID and the listening socket as fd 3.
# Checks: the daemon answers `status` on the inherited socket (several connections, so the
# listening socket is served, not one accepted connection); it creates no socket of its own
# (its --socket path stays absent); on SIGTERM it leaves the inherited socket file alone (it
# belongs to the socket unit). Plan paths that are not regular files (/dev/zero, a FIFO) are
# refused at once and the daemon keeps answering. And a daemon handed something that is not
# a listening UNIX socket as fd 3 refuses to start, saying why.
# Usage: daemon-socket-activation.sh BUILD_DIR SOURCE_DIR
set -u
build=$1 src=$2
imp=$build/cli/impasto
impastod=$build/daemon/impastod
[ -x "$imp" ] && [ -x "$impastod" ] || { echo "SKIP: $imp or $impastod not built"; exit 77; }
command -v systemd-socket-activate >/dev/null || { echo "SKIP: systemd-socket-activate not installed"; exit 77; }
tmp=$(mktemp -d /tmp/impasto-activation.XXXXXX)
. "$src/tests/integration/lib-daemon.sh"
trap lib_cleanup EXIT

# a rig config whose devices are never opened here (status does not touch them)
cat >"$tmp/rig.cfg" <<EOF
rig = { name = "activated"; calibration = "rig.json";
        cameras = ( { name = "cam0"; backend = "aravis"; address = "127.0.0.1"; } ); };
EOF
sock=$tmp/activated.sock
own=$tmp/own.sock
systemd-socket-activate -l "$sock" "$impastod" --rig "$tmp/rig.cfg" --socket "$own" --state-dir "$tmp/state" \
  >"$tmp/log" 2>&1 &
pid=$!
daemon_pid=$pid     # (lib_cleanup stops it)
for _ in $(seq 100); do [ -S "$sock" ] && break; sleep 0.05; done
check "systemd-socket-activate listens on $sock" test -S "$sock"

# the first connection starts impastod; three in a row must all be answered
for i in 1 2 3; do
  timeout 20 "$imp" status --socket "$sock" --json >"$tmp/status$i.json" 2>"$tmp/e$i"
  rc=$?
  check "status over the inherited socket, connection $i" [ $rc -eq 0 ]
done
check "it is impastod that answers (rig name from its config)" grep -q '"activated"' "$tmp/status3.json"
answered_pid=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["daemon"]["pid"])' "$tmp/status3.json" 2>/dev/null)
check "the daemon runs in the activated process (pid $answered_pid = $pid)" [ "$answered_pid" = "$pid" ]
check "the daemon logged that it was activated" grep -q "socket (activated)" "$tmp/log"
check "no socket of its own at --socket" test ! -e "$own"
fd_target=$(readlink "/proc/$pid/fd/3" 2>/dev/null)
check "fd 3 of the daemon is a socket" sh -c "case '$fd_target' in socket:*) true;; *) false;; esac"

# Without --plan-dir, plan paths are still only regular files: /dev/zero or a FIFO would
# have held the daemon's one event loop forever (a read that never ends or never starts).
mkfifo "$tmp/fifo.cfg"
for p in /dev/zero "$tmp/fifo.cfg"; do
  timeout 20 "$imp" plan validate "$p" --daemon --socket "$sock" >"$tmp/o" 2>"$tmp/e"; rc=$?
  check "plan validate $p: refused at once (exit 3), naming it" \
    sh -c "[ $rc -eq 3 ] && grep -q '$p: not a regular file' '$tmp/e'"
done
timeout 20 "$imp" status --socket "$sock" >/dev/null 2>&1
check "the daemon still answers" [ $? -eq 0 ]

kill -TERM "$pid"
wait "$pid"; rc=$?
daemon_pid=""
check "SIGTERM: exit 0" [ $rc -eq 0 ]
check "the socket unit's file is left to the unit" test -S "$sock"

# fd 3 that is not a listening socket: refused
: >"$tmp/not-a-socket"
sh -c 'LISTEN_PID=$$ LISTEN_FDS=1 exec "$0" "$@" 3<"'"$tmp"'/not-a-socket"' "$impastod" --rig "$tmp/rig.cfg" \
  --socket "$own" --state-dir "$tmp/state" >"$tmp/log2" 2>&1
rc=$?
check "fd 3 not a socket: impastod exits 1" [ $rc -eq 1 ]
check "and says why" grep -q "not a listening UNIX stream socket" "$tmp/log2"
check "and still creates no socket" test ! -e "$own"

cp "$tmp/log" "$tmp/impastod.log"
lib_finish
