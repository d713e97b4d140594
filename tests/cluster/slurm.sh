#!/usr/bin/env bash
# A real Slurm on this machine for the cluster tests: munged with its own key and socket,
# slurmctld and one slurmd on loopback with unprivileged ports, everything in a temporary
# folder (the packages' system services are not used). Debian bookworm's slurm-wlm and munge.
#
#   slurm.sh start STATE   writes the slurm.conf path to STATE (export SLURM_CONF=$(cat STATE))
#   slurm.sh stop STATE    stops the daemons and removes the folder
# Node: this machine's CPUs, proctrack/linuxproc and task/none (no cgroups needed), CPUs as the
# consumable resource so that tasks of one CPU run side by side.
set -euo pipefail
cmd="${1:?usage: slurm.sh start|stop STATE}"
state="${2:?usage: slurm.sh start|stop STATE}"
for b in munged slurmctld slurmd sbatch; do
  command -v "$b" > /dev/null || [[ -x /usr/sbin/$b ]] ||
    { echo "slurm.sh: $b is missing (apt-get install slurm-wlm munge)" >&2; exit 2; }
done
PATH="$PATH:/usr/sbin"
free_port() { /usr/bin/python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
stop() {
  [[ -f "$state.dir" ]] || return 0
  local dir pid
  dir="$(cat "$state.dir")"
  if [[ -f "$dir/slurm.conf" ]]; then SLURM_CONF="$dir/slurm.conf" scancel --quiet --user="$(id -un)" 2>/dev/null || true; fi
  for p in slurmd slurmctld munged; do
    pid="$(cat "$dir/$p.pid" 2>/dev/null || true)"
    [[ -n "$pid" ]] && kill "$pid" 2>/dev/null || true
  done
  for _ in $(seq 50); do
    local alive=0
    for p in slurmd slurmctld munged; do
      pid="$(cat "$dir/$p.pid" 2>/dev/null || true)"
      [[ -n "$pid" ]] && kill -0 "$pid" 2>/dev/null && alive=1
    done
    [[ $alive == 0 ]] && break
    sleep 0.1
  done
  rm -rf "$dir" "$state" "$state.dir"
}
wait_for() {  # $1: what, $2..: a command that succeeds once it is up
  local what="$1"; shift
  for _ in $(seq 100); do "$@" > /dev/null 2>&1 && return 0; sleep 0.2; done
  echo "slurm.sh: $what did not come up; its log:" >&2
  tail -n 20 "$dir/$what.log" >&2 || true
  exit 1
}
case "$cmd" in
  start)
    stop
    mkdir -p "$(dirname "$state")"
    dir="$(mktemp -d /tmp/brenier-slurm-XXXXXX)"
    chmod 0755 "$dir"
    echo "$dir" > "$state.dir"
    user="$(id -un)"
    mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
    chmod 0700 "$dir/munge"
    dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
    chmod 0400 "$dir/munge/munge.key"
    munged --force --socket="$dir/munge/socket" --key-file="$dir/munge/munge.key" \
      --pid-file="$dir/munged.pid" --log-file="$dir/munged.log" --seed-file="$dir/munge/seed"
    cpus="$(nproc --all)"
    mem="$(awk '/MemTotal/ {print int($2 / 1024 / 2)}' /proc/meminfo)"
    cat > "$dir/slurm.conf" <<CONF
ClusterName=brenier-test
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
SlurmUser=$user
SlurmdUser=$user
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/backfill
MpiDefault=none
ReturnToService=2
SwitchType=switch/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MinJobAge=60
KillWait=5
InactiveLimit=0
SlurmctldTimeout=30
SlurmdTimeout=60
NodeName=brenier-node NodeAddr=127.0.0.1 NodeHostname=$(hostname) CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
    export SLURM_CONF="$dir/slurm.conf"
    slurmctld -f "$SLURM_CONF" || { tail -n 20 "$dir/slurmctld.log" >&2; exit 1; }
    wait_for slurmctld scontrol ping
    slurmd -f "$SLURM_CONF" -N brenier-node || { tail -n 20 "$dir/slurmd.log" >&2; exit 1; }
    wait_for slurmd bash -c "sinfo -h -N -o %T | grep -Eq '^(idle|mixed|allocated)'"
    echo "$SLURM_CONF" > "$state"
    echo "Slurm up: $SLURM_CONF ($cpus CPUs)"
    ;;
  stop) stop ;;
  *) echo "slurm.sh: start or stop, not '$cmd'" >&2; exit 2 ;;
esac
