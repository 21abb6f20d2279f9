#!/usr/bin/env bash
# Proves the Slurm recipe of deploy/slurm/ on a real single-node Slurm:
# installs Debian's slurm-wlm (and munge) if missing, starts munged,
# slurmctld and slurmd on this machine with a throwaway configuration in
# WORK_DIR, submits deploy/slurm/batch.sbatch as an array job and
# deploy/slurm/merge.sbatch after it, runs the same batch locally with
# `coid batch`, and compares the two byte for byte. Exit 0 only when every
# compared file is identical. Needs root (apt, daemons); stops the daemons
# it started when it ends.
#
#   deploy/check-slurm.sh [WORK_DIR]          # default /tmp/coid-slurm-check
#
# Settings (environment): COID_CONFIG (default configs/default.toml),
# COID_RUNS (4), COID_SEED (7), SHARDS (2), TIMEOUT_S (1800).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
work="${1:-/tmp/coid-slurm-check}"
config="$(realpath "${COID_CONFIG:-$root/configs/default.toml}")"
runs="${COID_RUNS:-4}"
seed="${COID_SEED:-7}"
shards="${SHARDS:-2}"
timeout_s="${TIMEOUT_S:-1800}"
say() { printf 'check-slurm: %s\n' "$*"; }
if [ "$(id -u)" -ne 0 ]; then
    say "needs root (it installs slurm-wlm and starts munged, slurmctld, slurmd)" >&2
    exit 1
fi

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm from Debian"
    apt-get update -q >/dev/null
    DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge >/dev/null
fi
say "$(slurmctld -V)"

rm -rf "$work"
mkdir -p "$work"/{state,spool,log}
work="$(cd "$work" && pwd)"
host="$(hostname -s)"
mem_mb=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 512 ))
cat >"$work/slurm.conf" <<EOF
ClusterName=coid-check
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/log/slurmctld.log
SlurmdLogFile=$work/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$work/log/jobs.txt
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
MinJobAge=3600
NodeName=$host CPUs=$(nproc) RealMemory=$mem_mb State=UNKNOWN
PartitionName=check Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$work/slurm.conf"

# Daemons: munge (authentication), the controller and the node daemon.
started=()
stop() {
    for pid in "${started[@]}"; do kill "$pid" 2>/dev/null || true; done
}
trap stop EXIT
if [ ! -s /etc/munge/munge.key ]; then
    mkdir -p /etc/munge
    dd if=/dev/urandom bs=1 count=1024 of=/etc/munge/munge.key 2>/dev/null
    chmod 400 /etc/munge/munge.key
fi
if ! pgrep -x munged >/dev/null; then
    mkdir -p /run/munge /var/log/munge /var/lib/munge
    munged --force
    sleep 1
    started+=("$(cat /run/munge/munged.pid)")
fi
for _ in $(seq 10); do munge -n >/dev/null 2>&1 && break; sleep 1; done
munge -n >/dev/null || { say "munge does not answer; see /var/log/munge"; exit 1; }
slurmctld -i
sleep 1
started+=("$(cat "$work/slurmctld.pid")")
slurmd
sleep 1
started+=("$(cat "$work/slurmd.pid")")
for _ in $(seq 30); do
    state="$(sinfo -h -o %T | head -1)"
    [ "$state" = "idle" ] && break
    sleep 1
done
say "node $host: $(sinfo -h -o '%T, %c CPUs')"
[ "$state" = "idle" ] || { say "node never became idle"; exit 1; }

# Build once (the jobs run ./coid, which would otherwise build on first use).
cd "$root"
./coid --help >/dev/null

# The recipe, as a user runs it (one worker per array task here).
out="$work/slurm"
export COID_CONFIG="$config" COID_RUNS="$runs" COID_SEED="$seed" COID_OUT="$out"
array="$(sbatch --parsable --array=1-"$shards" --cpus-per-task=1 --mem-per-cpu=1G \
    --output="$work/log/batch-%A_%a.log" deploy/slurm/batch.sbatch)"
merge="$(sbatch --parsable --dependency=afterok:"$array" \
    --output="$work/log/merge-%j.log" deploy/slurm/merge.sbatch)"
say "submitted array job $array ($shards tasks, $runs runs) and merge job $merge"
start=$(date +%s)
while squeue -h -j "$array,$merge" 2>/dev/null | grep -q .; do
    if [ $(( $(date +%s) - start )) -gt "$timeout_s" ]; then
        say "timed out after $timeout_s s"; squeue; exit 1
    fi
    sleep 2
done
say "jobs finished in $(( $(date +%s) - start )) s:"
sed -n 's/.*JobId=\([0-9_]*\).*Name=\([^ ]*\).*JobState=\([A-Z]*\).*ExitCode=\([0-9:]*\).*/  job \1 \2 \3 exit \4/p' \
    "$work/log/jobs.txt"
if grep -v "JobState=COMPLETED" "$work/log/jobs.txt" | grep -q JobId; then
    say "a job did not complete; logs in $work/log"; exit 1
fi

# The same batch locally, then byte for byte.
./coid batch --quiet --config "$config" --runs "$runs" --seed "$seed" --workers 2 \
    --out "$work/local"
compared=0
while IFS= read -r f; do
    cmp -s "$out/merged/$f" "$work/local/$f" || { say "DIFFERS: $f"; exit 1; }
    compared=$((compared + 1))
done < <(cd "$work/local" && find . -type f | sort)
say "merged Slurm batch == local coid batch: $compared files byte-identical"
