# A one-node Slurm for palp's cluster test and benchmark (source this file; needs root):
# munged as the munge user on its own socket, slurmctld and slurmd with a slurm.conf in a temp
# dir, no systemd (recipe in docs/error_analysis.md). After `slurm_up`, $D is the temp dir (with
# log/ and out/), SLURM_CONF is exported and the node is idle; `slurm_down` stops the daemons
# and removes $D, whatever state they are in; `fail MESSAGE` prints the message and the tail of
# every log and output, and exits 1. The caller sets its own traps.

slurm_check_tools() {
  for prog in /usr/sbin/munged /usr/sbin/slurmctld /usr/sbin/slurmd sbatch srun squeue \
      scontrol mpirun; do
    command -v "$prog" > /dev/null || { echo "FAIL: $prog not found (tools/setup.sh installs" \
      "slurm-wlm, munge and openmpi-bin)"; exit 1; }
  done
  [[ $(id -u) -eq 0 ]] || { echo "FAIL: the one-node Slurm needs root (munged runs as munge)"; exit 1; }
}

fail() {
  echo "FAIL: $*"
  for f in "$D"/log/*.log "$D"/out/*; do
    [[ -f $f ]] && { echo "--- $f"; tail -n 20 "$f"; }
  done
  exit 1
}

MUNGED_PID="" CTLD_PID="" SLURMD_PID=""
D=$(mktemp -d /tmp/palp-slurm.XXXXXX)
chmod 0755 "$D"

slurm_down() {
  set +e
  if [[ -n $CTLD_PID ]]; then
    scancel --user=root > /dev/null 2>&1
    scontrol shutdown > /dev/null 2>&1
    for _ in $(seq 50); do
      kill -0 "$CTLD_PID" 2> /dev/null || kill -0 "$SLURMD_PID" 2> /dev/null || break
      sleep 0.1
    done
  fi
  for pid in $SLURMD_PID $CTLD_PID; do kill -0 "$pid" 2> /dev/null && kill "$pid"; done
  if [[ -n $MUNGED_PID ]]; then
    /usr/sbin/munged --stop --socket="$D/munge/socket" > /dev/null 2>&1 ||
      kill "$MUNGED_PID" 2> /dev/null
  fi
  rm -rf "$D"
}

slurm_up() {  # CPUS (default 2)
  local cpus=${1:-2}
  # munged on its own socket and files, as the munge user (it refuses root).
  install -d -o munge -g munge -m 0755 "$D/munge"
  local key=/etc/munge/munge.key
  if [[ ! -r $key ]]; then
    key=$D/munge/munge.key
    head -c 1024 /dev/urandom > "$key"
    chown munge:munge "$key"
    chmod 0400 "$key"
  fi
  runuser -u munge -- /usr/sbin/munged --socket="$D/munge/socket" --pid-file="$D/munge/pid" \
    --log-file="$D/munge/log" --seed-file="$D/munge/seed" --key-file="$key" ||
    fail "munged did not start"
  MUNGED_PID=$(cat "$D/munge/pid")
  munge -n --socket="$D/munge/socket" | unmunge --socket="$D/munge/socket" > /dev/null ||
    fail "munge round trip"

  # Ports of their own (another one-node Slurm may run on the machine).
  local port=$((20000 + $$ % 20000))
  mkdir -p "$D/state" "$D/spool" "$D/log" "$D/out"
  cat > "$D/slurm.conf" << EOF
ClusterName=palp
SlurmctldHost=localhost
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$D/munge/socket
CredType=cred/munge
StateSaveLocation=$D/state
SlurmdSpoolDir=$D/spool
SlurmctldPidFile=$D/slurmctld.pid
SlurmdPidFile=$D/slurmd.pid
SlurmctldLogFile=$D/log/slurmctld.log
SlurmdLogFile=$D/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=pmix
ReturnToService=2
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$cpus Sockets=1 CoresPerSocket=$cpus ThreadsPerCore=1 RealMemory=2000 State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
SchedulerParameters=batch_sched_delay=0,sched_min_interval=0
JobCompType=jobcomp/filetxt
JobCompLoc=$D/log/jobcomp.txt
EOF
  export SLURM_CONF=$D/slurm.conf
  /usr/sbin/slurmctld || fail "slurmctld did not start"
  for _ in $(seq 50); do [[ -s $D/slurmctld.pid ]] && break; sleep 0.1; done
  CTLD_PID=$(cat "$D/slurmctld.pid")
  /usr/sbin/slurmd -N localhost || fail "slurmd did not start"
  for _ in $(seq 50); do [[ -s $D/slurmd.pid ]] && break; sleep 0.1; done
  SLURMD_PID=$(cat "$D/slurmd.pid")
  for _ in $(seq 100); do
    [[ $(sinfo -h -n localhost -o %T 2> /dev/null) == idle ]] && break
    sleep 0.1
  done
  [[ $(sinfo -h -n localhost -o %T) == idle ]] || fail "the node did not come up"
  echo "slurm up (ctld $CTLD_PID, slurmd $SLURMD_PID)"
}

slurm_wait_job() {  # waits until job $1 (all its array tasks) has left the queue, at most $2 s
  local tenths=$((${2:-60} * 10))
  for _ in $(seq "$tenths"); do
    [[ -z $(squeue -h -j "$1" 2> /dev/null) ]] && return 0
    sleep 0.1
  done
  fail "job $1 still queued after ${2:-60} s"
}
