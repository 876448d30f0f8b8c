#!/usr/bin/env bash
# A single-node Slurm cluster on this machine, for trying campaigns through `sbatch` and for CI
# (`cargo xtask test` runs the campaign smoke test through it). Debian/Ubuntu packages
# `slurm-wlm` and `munge` (installed by `cargo xtask test` when missing; by hand:
# `apt-get install -y slurm-wlm munge`). Run as root.
#
#   tools/slurm-single-node.sh start    # write the configuration, start munged, slurmctld, slurmd
#   tools/slurm-single-node.sh status   # sinfo of the cluster
#   tools/slurm-single-node.sh stop     # stop the daemons this script started
#   tools/slurm-single-node.sh env      # print the export line for the client commands
#
# Everything lives in one state directory (default /tmp/rover-slurm, or $ROVER_SLURM_DIR):
# slurm.conf, the controller's state, the daemons' spool, logs and pid files. Nothing is written
# to /etc/slurm: the client commands (sbatch, squeue, scontrol) find the configuration through
# SLURM_CONF, so run `eval "$(tools/slurm-single-node.sh env)"` before using them by hand.
#
# The node is this machine (`hostname -s`) with its CPU count (`nproc`), partition `ci`;
# process tracking by /proc (proctrack/linuxproc), no cgroups, no accounting database.
# `start` is idempotent: daemons already running (their pid file names a live process) are kept.
# `stop` ends only the processes named by this script's pid files (munged only if this script
# started it). docs/campaigns.md explains what to change for a real cluster.
set -euo pipefail

DIR="${ROVER_SLURM_DIR:-/tmp/rover-slurm}"
CONF="$DIR/slurm.conf"
NODE="$(hostname -s)"
CPUS="${ROVER_SLURM_CPUS:-$(nproc)}"
MUNGE_SOCKET=/run/munge/munge.socket.2

alive() { # pid file -> 0 when it names a live process
    [[ -s "$1" ]] && kill -0 "$(cat "$1")" 2>/dev/null
}

write_conf() {
    mkdir -p "$DIR/ctld" "$DIR/spool" "$DIR/log"
    # Memory in MB that slurmd reports (RealMemory must not exceed it).
    local mem
    mem=$(awk '/MemTotal/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)
    cat > "$CONF" <<EOF
# Written by tools/slurm-single-node.sh: a single-node cluster on $NODE.
ClusterName=rover-local
SlurmctldHost=$NODE
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CryptoType=crypto/munge
SlurmctldPort=6817
SlurmdPort=6818
StateSaveLocation=$DIR/ctld
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MaxArraySize=10001
MaxJobCount=20000
# Finished jobs stay visible to scontrol for 10 minutes (no accounting database here).
MinJobAge=600
SlurmctldTimeout=30
SlurmdTimeout=30
InactiveLimit=0
KillWait=10
Waittime=0
NodeName=$NODE CPUs=$CPUS RealMemory=$mem State=UNKNOWN
PartitionName=ci Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
}

start() {
    command -v slurmctld >/dev/null && command -v munged >/dev/null || {
        echo "slurm-wlm and munge are not installed: apt-get install -y slurm-wlm munge" >&2
        exit 1
    }
    write_conf
    if [[ -S "$MUNGE_SOCKET" ]] && munge -n </dev/null >/dev/null 2>&1; then
        echo "munged: running"
    else
        mkdir -p /run/munge /var/log/munge /var/lib/munge
        chown munge:munge /run/munge /var/log/munge /var/lib/munge
        [[ -s /etc/munge/munge.key ]] || runuser -u munge -- mungekey --create
        runuser -u munge -- /usr/sbin/munged
        touch "$DIR/munged.started-here"
        echo "munged: started"
    fi
    if alive "$DIR/slurmctld.pid"; then
        echo "slurmctld: running"
    else
        # -i: ignore state files from an earlier cluster in this directory.
        slurmctld -f "$CONF" -i
        echo "slurmctld: started"
    fi
    if alive "$DIR/slurmd.pid"; then
        echo "slurmd: running"
    else
        slurmd -f "$CONF"
        echo "slurmd: started"
    fi
    export SLURM_CONF="$CONF"
    # Wait (at most 60 s) until the node takes jobs.
    for _ in $(seq 60); do
        state=$(sinfo -h -n "$NODE" -o %t 2>/dev/null || true)
        if [[ "$state" == idle* || "$state" == mix* || "$state" == alloc* ]]; then
            echo "node $NODE: $state ($CPUS CPUs), partition ci; export SLURM_CONF=$CONF"
            return 0
        fi
        if [[ "$state" == down* || "$state" == drain* ]]; then
            scontrol update nodename="$NODE" state=resume 2>/dev/null || true
        fi
        sleep 1
    done
    echo "the node did not come up; logs in $DIR/log" >&2
    tail -n 20 "$DIR/log/slurmctld.log" "$DIR/log/slurmd.log" >&2 || true
    exit 1
}

stop_one() { # name, pid file
    if alive "$2"; then
        local pid
        pid=$(cat "$2")
        kill "$pid"
        for _ in $(seq 30); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.5
        done
        echo "$1: stopped"
    fi
    rm -f "$2"
}

stop() {
    stop_one slurmd "$DIR/slurmd.pid"
    stop_one slurmctld "$DIR/slurmctld.pid"
    if [[ -e "$DIR/munged.started-here" ]]; then
        stop_one munged /run/munge/munged.pid
        rm -f "$DIR/munged.started-here"
    fi
}

case "${1:-}" in
start) start ;;
stop) stop ;;
status) SLURM_CONF="$CONF" sinfo ;;
env) echo "export SLURM_CONF=$CONF" ;;
*)
    echo "usage: $0 start|stop|status|env" >&2
    exit 2
    ;;
esac
