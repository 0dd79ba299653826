#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the shard test (tests/slurm.rs) and for trying
# the array job of docs/cluster.md without a cluster: munged, slurmctld and slurmd as root, with
# their configuration, state and logs under DIR.
#   scripts/slurm/local-cluster.sh start DIR   # prints SLURM_CONF=DIR/slurm.conf once the node is idle
#   scripts/slurm/local-cluster.sh stop DIR
# Ports: 6817/6818 unless DC_SLURM_PORTS="CTLD SLURMD" (fixed ports, never probed: a free port
# found by binding and releasing can be taken by another program before slurmctld binds it).
set -euo pipefail
what="${1:?usage: local-cluster.sh start|stop DIR}"
dir="$(realpath -m "${2:?usage: local-cluster.sh start|stop DIR}")"
read -r ctld_port slurmd_port <<<"${DC_SLURM_PORTS:-6817 6818}"

stop() {
  for pid in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munged.pid"; do
    [ -s "$pid" ] && kill "$(cat "$pid")" 2>/dev/null || true
  done
  sleep 1
}

if [ "$what" = stop ]; then
  stop
  exit 0
fi
[ "$what" = start ] || { echo "local-cluster.sh: unknown command \`$what\` (start|stop)" >&2; exit 2; }
[ "$(id -u)" = 0 ] || { echo "local-cluster.sh: slurmd must run as root (it starts jobs as their users)" >&2; exit 1; }
for p in munged mungekey slurmctld slurmd sbatch sinfo; do
  command -v "$p" >/dev/null || [ -x "/usr/sbin/$p" ] || { echo "local-cluster.sh: \`$p\` not found (Debian: apt-get install slurm-wlm munge)" >&2; exit 1; }
done
export PATH="$PATH:/usr/sbin"
mkdir -p "$dir"/{state,spool,munge,log}
chmod 700 "$dir/munge"

# munge: a key of our own and a socket under DIR, so a system munged (if any) is left alone.
key="$dir/munge/munge.key"
[ -s "$key" ] || mungekey --create --keyfile="$key" 2>/dev/null || dd if=/dev/urandom of="$key" bs=1024 count=1 status=none
chmod 400 "$key"
socket="$dir/munge/munge.socket"
munged --key-file="$key" --socket="$socket" --pid-file="$dir/munged.pid" \
  --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munge.seed" --force
host="$(hostname -s)"
cpus="$(nproc)"
mem_mb="$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)"
cat >"$dir/slurm.conf" <<CONF
ClusterName=dc-local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
AuthType=auth/munge
AuthInfo=socket=$socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
ReturnToService=2
SlurmdTimeout=60
MinJobAge=600
NodeName=$host CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=local Nodes=ALL Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
CONF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -c -f "$SLURM_CONF"
slurmd -c -f "$SLURM_CONF"
for _ in $(seq 1 60); do
  state="$(sinfo -h -N -o %t 2>/dev/null | head -1 || true)"
  if [ "$state" = idle ] || [ "$state" = mix ]; then
    echo "SLURM_CONF=$SLURM_CONF"
    exit 0
  fi
  sleep 1
done
echo "local-cluster.sh: the node did not come up (state \`${state:-none}\`); logs in $dir/log:" >&2
tail -5 "$dir"/log/*.log >&2 || true
stop
exit 1
