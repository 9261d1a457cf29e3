# A one-node Slurm for tests and benches (docs/scale-out.md, "A test cluster on one machine"),
# sourced after $tmp and $scale are set: slurm_start DIR starts munged, slurmctld and slurmd
# in the foreground with a generated slurm.conf and every state file under DIR, exports
# SLURM_CONF, and returns once the node is idle (1 when it does not come up); stop_all stops
# whatever was started (call it from the EXIT trap: it runs on failures too).
# Run it inside `unshare -n` with lo up and 127.0.0.2 on lo (Slurm's ports are 6817, 6818).
pids=()
stop_all() {
  scancel --full --quiet -u "$(id -un)" >/dev/null 2>&1
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null; done
  for p in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$p" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$p" 2>/dev/null
    wait "$p" 2>/dev/null
  done
  pids=()
}

slurm_start() {
  local d=$1 up=0 node
  mkdir -p "$d/munge" "$d/state" "$d/spool" && chmod 0700 "$d/munge"
  mungekey -c -k "$d/munge/munge.key" >/dev/null 2>&1 || { echo "mungekey failed"; return 1; }
  munged -F --socket="$d/munge.socket" --key-file="$d/munge/munge.key" --pid-file="$d/munged.pid" \
    --seed-file="$d/munge.seed" --log-file="$d/munged.log" --force >/dev/null 2>&1 &
  pids+=($!)
  node=$(slurmd -C | head -1)
  cat >"$d/slurm.conf" <<EOF
ClusterName=impasto-test
SlurmctldHost=$(hostname)
SlurmUser=$(id -un)
AuthType=auth/munge
AuthInfo=socket=$d/munge.socket
CredType=cred/munge
StateSaveLocation=$d/state
SlurmdSpoolDir=$d/spool
SlurmctldPidFile=$d/slurmctld.pid
SlurmdPidFile=$d/slurmd.pid
SlurmctldLogFile=$d/slurmctld.log
SlurmdLogFile=$d/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$d/jobcomp.txt
MailProg=/bin/true
MinJobAge=600
KillWait=2
SchedulerParameters=sched_interval=1
$node State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
  export SLURM_CONF=$d/slurm.conf
  for _ in $(seq 50); do [ -S "$d/munge.socket" ] && break; sleep 0.1; done
  slurmctld -D -f "$SLURM_CONF" >"$d/slurmctld.out" 2>&1 &
  pids+=($!)
  slurmd -D -f "$SLURM_CONF" >"$d/slurmd.out" 2>&1 &
  pids+=($!)
  for _ in $(seq $((100 * ${scale:-1}))); do
    [ "$(sinfo -h -N -o %t 2>/dev/null)" = idle ] && { up=1; break; }
    sleep 0.2
  done
  [ $up -eq 1 ] || { tail -5 "$d/slurmctld.log" "$d/slurmd.log"; return 1; }
}

# slurm_wait_for DESC SECONDS CMD...: polls CMD every 0.2 s (SECONDS × $scale)
slurm_wait_for() {
  local what=$1 s=$2; shift 2
  for _ in $(seq $((s * 5 * scale))); do "$@" && return 0; sleep 0.2; done
  echo "FAIL timed out waiting: $what"; return 1
}

# same_copy A B: every file byte for byte; copy.json without timings, RSS and the capture path
slurm_same_copy() {
  python3 - "$1" "$2" <<'PY'
import json, os, sys
a, b = sys.argv[1], sys.argv[2]
def files(d):
    return sorted(os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs)
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if not k.startswith("seconds") and k not in ("peak_rss_kib", "capture")}
    if isinstance(x, list):
        return [strip(v) for v in x]
    return x
fa, fb = [f for f in files(a) if f != "result.json"], [f for f in files(b) if f != "result.json"]
if fa != fb:
    sys.exit("different files: %s vs %s" % (fa, fb))
for f in fa:
    pa, pb = os.path.join(a, f), os.path.join(b, f)
    if f == "copy.json":
        if strip(json.load(open(pa))) != strip(json.load(open(pb))):
            sys.exit("copy.json differs beyond timings")
    elif open(pa, "rb").read() != open(pb, "rb").read():
        sys.exit(f + " differs")
PY
}

# slurm_same_mosaic A B: two outputs of `impasto mosaic`, every file byte for byte except
# mosaic.json, compared without its tiles' "copy" paths (where the tile copies were read).
slurm_same_mosaic() {
  python3 - "$1" "$2" <<'PY'
import json, os, sys
a, b = sys.argv[1], sys.argv[2]
def files(d):
    return sorted(os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs)
def strip(x):
    if isinstance(x, dict):
        return {k: strip(v) for k, v in x.items() if k != "copy"}
    return [strip(v) for v in x] if isinstance(x, list) else x
if files(a) != files(b):
    sys.exit("different files")
for f in files(a):
    pa, pb = os.path.join(a, f), os.path.join(b, f)
    if f == "mosaic.json":
        if strip(json.load(open(pa))) != strip(json.load(open(pb))):
            sys.exit("mosaic.json differs beyond the tile copies' paths")
    elif open(pa, "rb").read() != open(pb, "rb").read():
        sys.exit(f + " differs")
PY
}
