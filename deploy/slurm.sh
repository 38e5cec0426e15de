#!/usr/bin/env bash
# A single-node Slurm on this machine, for testing `selkd experiment plan --slurm`'s job array on
# the engine clusters run it on. Everything it starts lives in DIR: its own munge key and socket,
# its own slurm.conf and state, its own ports, so it touches no system-wide Slurm or munge.
#
#   bash deploy/slurm.sh install      # Debian's slurm-wlm and munge (needs root; once)
#   bash deploy/slurm.sh up DIR       # munged, slurmctld, slurmd; then: export SLURM_CONF=DIR/slurm.conf
#   bash deploy/slurm.sh down DIR     # stops them
#
# The daemons run as the calling user (Slurm's own user is this user); `up` waits until the node
# takes jobs. Ports: SLURM_TEST_PORT (slurmctld) and the next one (slurmd), default 16817.
set -euo pipefail

need() { command -v "$1" >/dev/null 2>&1; }

case "${1:-}" in
install)
    if need slurmctld && need slurmd && need sbatch && need munged; then
        echo "slurm: slurm-wlm and munge already installed" >&2
        exit 0
    fi
    [ "$(id -u)" = 0 ] || { echo "slurm: installing Debian's slurm-wlm and munge needs root (apt-get)" >&2; exit 1; }
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q slurm-wlm munge >/dev/null 2>&1 \
        || { apt-get update -q >/dev/null && apt-get install -y -q slurm-wlm munge >/dev/null; }
    echo "slurm: installed $(sbatch --version)" >&2
    ;;
up)
    dir=${2:?usage: deploy/slurm.sh up DIR}
    for b in munged slurmctld slurmd sbatch; do
        need "$b" || { echo "slurm: $b is missing; run: bash deploy/slurm.sh install" >&2; exit 1; }
    done
    mkdir -p "$dir"/{state,spool,log}
    dir=$(cd "$dir" && pwd)
    chmod 700 "$dir"
    user=$(id -un)
    port=${SLURM_TEST_PORT:-16817}
    host=$(hostname -s)
    cpus=$(nproc)
    mem=$(awk '/MemTotal/ { print int($2 / 1024) }' /proc/meminfo)
    # munge: a fresh key of our own; munged refuses group- or world-readable keys.
    ( umask 077; head -c 1024 /dev/urandom > "$dir/munge.key" )
    munged --force --socket="$dir/munge.socket" --key-file="$dir/munge.key" \
        --pid-file="$dir/munged.pid" --log-file="$dir/log/munged.log" --seed-file="$dir/munged.seed"
    cat > "$dir/slurm.conf" <<EOF
# Written by deploy/slurm.sh: a one-node cluster for tests.
ClusterName=selkd-test
SlurmctldHost=$host
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$port
SlurmdPort=$((port + 1))
AuthType=auth/munge
AuthInfo=socket=$dir/munge.socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SwitchType=switch/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
# Seconds between a job's SIGTERM and its SIGKILL: room for a run to write its checkpoint.
KillWait=60
# A requeued job may start again at once (Slurm's default holds it back for a while).
MinJobAge=2
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
    export SLURM_CONF="$dir/slurm.conf"
    slurmctld -f "$SLURM_CONF"
    slurmd -f "$SLURM_CONF"
    for _ in $(seq 1 60); do
        if state=$(sinfo -h -o %T 2>/dev/null) && [ "$state" = idle ]; then
            echo "slurm: up in $dir (node $host, $cpus CPUs); export SLURM_CONF=$SLURM_CONF" >&2
            exit 0
        fi
        sleep 1
    done
    echo "slurm: the node did not become idle within 60 s (state: ${state:-none}); see $dir/log/" >&2
    exit 1
    ;;
down)
    dir=${2:?usage: deploy/slurm.sh down DIR}
    for d in slurmd slurmctld munged; do
        if [ -f "$dir/$d.pid" ]; then kill "$(cat "$dir/$d.pid")" 2>/dev/null || true; fi
    done
    ;;
*)
    echo "slurm: say install, up DIR or down DIR; see the top of deploy/slurm.sh" >&2
    exit 1
    ;;
esac
