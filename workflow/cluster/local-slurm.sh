#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the cluster tests and for trying the
# slurm profile without a cluster:
#
#   workflow/cluster/local-slurm.sh start    # write the config, start the daemons, wait for sinfo
#   workflow/cluster/local-slurm.sh status   # daemons and the node's state (exit 0 when usable)
#   workflow/cluster/local-slurm.sh stop     # cancel its jobs, stop the daemons, remove its state
#
# Needs root and Debian's slurm-wlm, munge, slurmdbd and mariadb-server (`make slurm-packages`).
# There is no systemd: the daemons are started by hand. Everything listens on 127.0.0.1 only.
#
# Layout: one node (this host's CPUs and memory from `slurmd -C`), partitions `main` (default)
# and `gpu`. The gpu partition has no GPU device: the node declares one `gpu` generic resource
# with /dev/null as its device file, so that the shipped profile's `gpu: 1` request (sbatch
# --gpus=1) is accepted as it would be on a real GPU partition; the avatar then runs on the
# CPU (device auto).
#
# Accounting: `sacct` is what the tests and the report read (requested memory, time limit,
# partition, elapsed, CPU time, MaxRSS). Without slurmdbd, sacct fails ("accounting storage is
# disabled") and jobcomp/filetxt records neither CPU time nor memory, so this runs slurmdbd on
# a private MariaDB (its own data folder, 127.0.0.1 only, a random password kept in the state
# folder) with JobAcctGatherType=jobacct_gather/linux sampling every second.
# One account, `signsplat`, holds the calling user (the plugin validates the account).
#
# Clients (sbatch, srun inside jobs, sacct) read /etc/slurm/slurm.conf: the Snakemake SLURM
# plugin's job step drops SLURM_* variables (SLURM_CONF too) before its inner srun, so a
# private SLURM_CONF would not reach it. That file is a link to this cluster's config, made
# only when no other config is there and removed by `stop`.
#
# Settings (environment): SIGNSPLAT_SLURM_DIR (state folder, default /tmp/signsplat-slurm),
# SIGNSPLAT_SLURM_PORT (slurmctld port; slurmd, slurmdbd and MariaDB use the next three).
set -euo pipefail

STATE=${SIGNSPLAT_SLURM_DIR:-/tmp/signsplat-slurm}
PORT=${SIGNSPLAT_SLURM_PORT:-6817}
CLUSTER=signsplat
ACCOUNT=signsplat
ETC_CONF=/etc/slurm/slurm.conf
CONF=$STATE/etc/slurm.conf
SOCK=$STATE/run/mysqld.sock
HOST=$(hostname -s)
USER_NAME=$(id -un)
export SLURM_CONF=$CONF  # the daemons read slurmdbd.conf / gres.conf beside it

say() { echo "local-slurm: $*"; }
die() { echo "local-slurm: $*" >&2; exit "${2:-1}"; }

need() {
    [ "$(id -u)" = 0 ] || die "needs root (munged, slurmd and slurmdbd run as root here)" 2
    local missing=()
    for cmd in munged slurmctld slurmd slurmdbd sbatch sacct sacctmgr mariadbd mariadb-install-db; do
        command -v "$cmd" >/dev/null 2>&1 || missing+=("$cmd")
    done
    [ ${#missing[@]} = 0 ] || die "missing ${missing[*]}: install with 'make slurm-packages' \
(apt-get install slurm-wlm munge slurmdbd mariadb-server)" 2
}

pid_alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

wait_for() {  # wait_for SECONDS DESCRIPTION COMMAND...
    local seconds=$1 what=$2; shift 2
    local end=$((SECONDS + seconds))
    until "$@" >/dev/null 2>&1; do
        [ $SECONDS -lt $end ] || die "timed out after ${seconds}s waiting for $what (logs: $STATE/log)"
        sleep 0.5
    done
}

node_state() { sinfo -h -N -n "$HOST" -o %t 2>/dev/null | head -1; }
node_usable() { case "$(node_state)" in idle|mix|mixed|alloc|allocated|comp*) return 0;; esac; return 1; }
munge_ok() { munge -n </dev/null 2>/dev/null | unmunge >/dev/null 2>&1; }

start_munge() {
    if munge_ok; then return; fi
    mkdir -p /run/munge && chown munge:munge /run/munge && chmod 755 /run/munge
    [ -f /etc/munge/munge.key ] || runuser -u munge -- mungekey --create
    # munge's own log and pid file (it refuses files it does not own)
    runuser -u munge -- munged 2>>"$STATE/log/munged.log" 9>&- \
        || die "munged did not start ($STATE/log/munged.log, /var/log/munge/munged.log)"
    cp /run/munge/munged.pid "$STATE/run/munged.pid"  # started here: stopped by `stop`
    wait_for 10 munged munge_ok
}

start_database() {
    mariadb-install-db --no-defaults --datadir="$STATE/db" --user=root \
        --auth-root-authentication-method=socket --skip-test-db >"$STATE/log/mariadb-install.log" 2>&1 \
        || die "mariadb-install-db failed ($STATE/log/mariadb-install.log)"
    setsid mariadbd --no-defaults --datadir="$STATE/db" --socket="$SOCK" --port=$((PORT + 3)) \
        --bind-address=127.0.0.1 --skip-name-resolve --user=root --pid-file="$STATE/run/mariadbd.pid" \
        --log-error="$STATE/log/mariadbd.log" --innodb-buffer-pool-size=64M \
        --innodb-lock-wait-timeout=900 </dev/null >/dev/null 2>&1 9>&- &
    wait_for 60 MariaDB mariadb-admin --no-defaults --socket="$SOCK" ping
    local pass
    pass=$(head -c 18 /dev/urandom | base64 | tr -dc 'A-Za-z0-9')
    mariadb --no-defaults --socket="$SOCK" -e "CREATE USER 'slurm'@'127.0.0.1' IDENTIFIED BY '$pass';
        GRANT ALL ON slurm_acct_db.* TO 'slurm'@'127.0.0.1';"
    (umask 077; cat >"$STATE/etc/slurmdbd.conf" <<EOF
# written by workflow/cluster/local-slurm.sh
AuthType=auth/munge
DbdHost=$HOST
DbdAddr=127.0.0.1
DbdPort=$((PORT + 2))
SlurmUser=root
LogFile=$STATE/log/slurmdbd.log
PidFile=$STATE/run/slurmdbd.pid
StorageType=accounting_storage/mysql
StorageHost=127.0.0.1
StoragePort=$((PORT + 3))
StorageUser=slurm
StoragePass=$pass
StorageLoc=slurm_acct_db
EOF
    )
}

write_config() {
    local node proctrack=proctrack/linuxproc
    node=$(slurmd -C | head -1)  # NodeName=<host> CPUs=.. Boards=.. ... RealMemory=..
    [[ $node == NodeName=* ]] || die "slurmd -C gave no node line: $node"
    # Process tracking by cgroup where the cgroup v1 freezer is there: a cancelled job's
    # processes are then all stopped. linuxproc follows parent links only, and a stage whose
    # shell was stopped first (its parent gone) escaped a cancel and ran on (seen here).
    if [ -d /sys/fs/cgroup/freezer ] && [ -w /sys/fs/cgroup/freezer ]; then
        proctrack=proctrack/cgroup
        printf '%s\n' "CgroupPlugin=cgroup/v1" "CgroupMountpoint=/sys/fs/cgroup" \
            "CgroupAutomount=no" "ConstrainCores=no" "ConstrainRAMSpace=no" \
            "ConstrainDevices=no" >"$STATE/etc/cgroup.conf"
    else
        say "no cgroup v1 freezer: proctrack/linuxproc (a process whose parent ended first can outlive a cancelled job)"
    fi
    cat >"$CONF" <<EOF
# written by workflow/cluster/local-slurm.sh: a single-node test cluster on this machine
ClusterName=$CLUSTER
SlurmctldHost=$HOST(127.0.0.1)
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
CommunicationParameters=NoInAddrAny,NoCtldInAddrAny
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$STATE/spool/ctld
SlurmdSpoolDir=$STATE/spool/d
SlurmctldPidFile=$STATE/run/slurmctld.pid
SlurmdPidFile=$STATE/run/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
ProctrackType=$proctrack
TaskPlugin=task/none
MpiDefault=none
ReturnToService=2
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
MinJobAge=300
EnforcePartLimits=ALL
KillWait=5
GresTypes=gpu
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=task=1
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=127.0.0.1
AccountingStoragePort=$((PORT + 2))
AccountingStorageEnforce=associations
AccountingStorageTRES=gres/gpu
AccountingStoreFlags=job_comment
JobCompType=jobcomp/none
$node NodeAddr=127.0.0.1 Gres=gpu:1 State=UNKNOWN
PartitionName=main Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
PartitionName=gpu Nodes=$HOST MaxTime=INFINITE State=UP
EOF
    # one `gpu` resource with no GPU behind it (see the header): Slurm's gres/gpu wants a
    # device file, /dev/null stands in (task/none: nothing is constrained by it)
    printf 'AutoDetect=off\nNodeName=%s Name=gpu File=/dev/null\n' "$HOST" >"$STATE/etc/gres.conf"
}

link_config() {
    mkdir -p /etc/slurm
    if [ -e "$ETC_CONF" ] || [ -L "$ETC_CONF" ]; then
        [ "$(readlink "$ETC_CONF" || true)" = "$CONF" ] \
            || die "$ETC_CONF exists and is not this test cluster's: not touching a real SLURM set-up"
        return
    fi
    ln -s "$CONF" "$ETC_CONF"
}

start() {
    need
    if status >/dev/null 2>&1; then say "already running ($STATE)"; return; fi
    if [ -e "$ETC_CONF" ] || [ -L "$ETC_CONF" ]; then
        [ "$(readlink "$ETC_CONF" || true)" = "$CONF" ] \
            || die "$ETC_CONF exists and is not this test cluster's: not touching a real SLURM set-up"
    fi
    [ -d "$STATE" ] && stop >/dev/null 2>&1 || true
    mkdir -p "$STATE"/{etc,spool/ctld,spool/d,log,run,db}
    start_munge
    write_config
    link_config
    start_database
    slurmdbd 9>&- || die "slurmdbd did not start ($STATE/log/slurmdbd.log)"
    wait_for 60 slurmdbd sacctmgr -n list cluster
    sacctmgr -i add cluster "$CLUSTER" >/dev/null
    sacctmgr -i add account "$ACCOUNT" Description="SignSplat test cluster" Organization=signsplat >/dev/null
    sacctmgr -i add user "$USER_NAME" Account="$ACCOUNT" DefaultAccount="$ACCOUNT" >/dev/null
    slurmctld 9>&- || die "slurmctld did not start ($STATE/log/slurmctld.log)"
    wait_for 30 slurmctld scontrol ping
    slurmd 9>&- || die "slurmd did not start ($STATE/log/slurmd.log)"
    wait_for 60 "the node to be idle in sinfo" node_usable
    say "running: $(sinfo -h -o '%P %a %D %t %c CPUs %m MB' | tr '\n' ';') state in $STATE"
}

status() {
    local ok=0
    for d in slurmctld slurmd slurmdbd mariadbd; do
        if pid_alive "$STATE/run/$d.pid"; then echo "$d: running (pid $(cat "$STATE/run/$d.pid"))"
        else echo "$d: not running"; ok=1; fi
    done
    munge_ok && echo "munged: running" || { echo "munged: not running"; ok=1; }
    if [ $ok = 0 ] && node_usable; then
        sinfo
        return 0
    fi
    if pid_alive "$STATE/run/slurmctld.pid"; then echo "node: $(node_state || true)"; fi
    return 3
}

stop_pid() {  # stop_pid NAME: SIGTERM, then wait up to 15 s
    local f=$STATE/run/$1.pid
    pid_alive "$f" || return 0
    local pid; pid=$(cat "$f")
    kill "$pid" 2>/dev/null || true
    for _ in $(seq 30); do kill -0 "$pid" 2>/dev/null || return 0; sleep 0.5; done
    kill -9 "$pid" 2>/dev/null || true
}

stop() {
    if pid_alive "$STATE/run/slurmctld.pid"; then
        local jobs; jobs=$(squeue -h -o %i 2>/dev/null || true)
        if [ -n "$jobs" ]; then
            # shellcheck disable=SC2086
            scancel $jobs 2>/dev/null || true
            for _ in $(seq 30); do [ -z "$(squeue -h -o %i 2>/dev/null)" ] && break; sleep 0.5; done
        fi
    fi
    stop_pid slurmd
    stop_pid slurmctld
    stop_pid slurmdbd
    stop_pid mariadbd
    stop_pid munged  # only when started by `start` (its pid file is in the state folder)
    if [ "$(readlink "$ETC_CONF" 2>/dev/null || true)" = "$CONF" ]; then rm -f "$ETC_CONF"; fi
    case "$STATE" in /tmp/*|*signsplat-slurm*) rm -rf "$STATE";; esac
    say "stopped"
}

locked() {  # one start or stop at a time (parallel test processes); the daemons are
    # started with fd 9 closed, or they would hold the lock for their whole life
    exec 9>>"$STATE.lock"
    flock 9
    "$@"
}

case "${1:-}" in
    start) locked start ;;
    stop) locked stop ;;
    status) status ;;
    *) echo "usage: $0 start|stop|status" >&2; exit 64 ;;
esac
