#!/bin/sh
# impastod.conf refused with FILE:LINE: FIELD and what was expected, before the daemon binds
# anything (daemon/conf.c), and scheduler = "slurm" without its --scheduler-config refused
# rather than run locally (daemon/main.c). Each check fails if its refusal is removed: the
# daemon would then go on to start (no exit 2) or print a message without the line.
# Usage: daemon-conf.sh BUILD_DIR
set -u
D="$1/daemon/impastod"
[ -x "$D" ] || { echo "no $D"; exit 77; }
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail=0
check() {       # NAME EXPECTED-SUBSTRING CONF-TEXT
  printf "$3" > "$T/$1.conf"
  timeout 20 "$D" --config "$T/$1.conf" --state-dir "$T/state" --socket "$T/sock" > "$T/out" 2>&1
  rc=$?
  if [ $rc -ne 2 ]; then echo "FAIL $1: exit $rc, expected 2"; cat "$T/out"; fail=1; return; fi
  if ! grep -qF -- "$2" "$T/out"; then echo "FAIL $1: no \"$2\" in:"; cat "$T/out"; fail=1; return; fi
  echo "ok   $1"
}
check unknown    "unknown.conf:3: impastod: unknown field colour" 'impastod = {\n  rig = "/x/rig.cfg";\n  colour = 3;\n};\n'
check relative   "relative.conf:2: impastod.state_dir: expected an absolute path" 'impastod = {\n  state_dir = "var/lib";\n};\n'
check enum       "enum.conf:3: impastod.resume: expected one of" 'impastod = {\n\n  resume = "sometimes";\n};\n'
check range      "range.conf:2: impastod.hook_timeout_s: expected an integer in [1, 3600]" 'impastod = {\n  hook_timeout_s = 0;\n};\n'
check syntax     "syntax.conf:2" 'impastod = {\n  resume = ;\n};\n'
# Slurm: impastod.scheduler = "slurm" with the top-level slurm = { … } group of the same file
check slurm      'slurm.conf: slurm.shared_dir: required with impastod.scheduler = "slurm"' 'impastod = {\n  scheduler = "slurm";\n};\n'
check nested     'nested.conf:3: impastod.slurm: the slurm = { … } group goes at the top level' 'impastod = {\n  scheduler = "slurm";\n  slurm = { shared_dir = "/x"; };\n};\n'
check slurmfield 'slurmfield.conf:5: slurm: unknown field cpus' 'impastod = {\n  scheduler = "slurm";\n};\nslurm = {\n  cpus = 2;\n  shared_dir = "/x";\n};\n'
# accepted: the settings come from impastod.conf; --scheduler-config overrides them
started() {     # NAME EXPECTED-LOG-LINE CONF-TEXT [OPTIONS...]: impastod goes past its config
  name=$1 want=$2; printf "$3" > "$T/$name.conf"; shift 3
  timeout 3 "$D" --config "$T/$name.conf" --state-dir "$T/state" --socket "$T/sock" "$@" > "$T/out" 2>&1
  if grep -q "error: config:" "$T/out" || ! grep -qF -- "$want" "$T/out"; then
    echo "FAIL $name: no \"$want\" (or a config error) in:"; cat "$T/out"; fail=1
  else echo "ok   $name"; fi
}
slurm_conf='impastod = {\n  scheduler = "slurm";\n};\nslurm = {\n  shared_dir = "/srv/shared";\n  partition = "imaging";\n};\n'
started slurmconf "scheduler slurm: batches in /srv/shared/batches, partition imaging" "$slurm_conf"
printf 'scheduler = "slurm";\nslurm = { shared_dir = "/srv/other"; };\n' > "$T/sched.conf"
started override "scheduler slurm: batches in /srv/other/batches, partition (default)" "$slurm_conf" \
  --scheduler-config "$T/sched.conf"
# a --config that does not exist is an error, not the defaults
timeout 20 "$D" --config "$T/none.conf" --state-dir "$T/state" --socket "$T/sock" > "$T/out" 2>&1
rc=$?
if [ $rc -ne 2 ] || ! grep -qF "none.conf" "$T/out"; then echo "FAIL missing: exit $rc"; cat "$T/out"; fail=1; else echo "ok   missing"; fi
exit $fail
