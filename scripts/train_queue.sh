#!/usr/bin/env bash
# Run the commands of a queue file, one line each, with N workers pulling lines in order.
#   scripts/train_queue.sh QUEUE_FILE [N_WORKERS]
# A line is claimed under a lock and marked "#started" when taken; it becomes "#done" or
# "#failed(rc)" when it ends, so a queue can be appended to while it runs and resumed after
# a kill (re-queue "#started" lines by removing the mark: training resumes from its resume point).
# Runs at low priority (nice 10) so tests and notebooks stay responsive. Started in a session of its
# own (`setsid scripts/train_queue.sh ...`), it also lowers that session's autogroup to nice 10: Linux
# shares the CPU fairly between sessions first, so nice alone would still give a test run in another
# session only its session's share. (A kernel with autogroups off reads the file empty: nothing to do.)
set -u
if [ -w /proc/self/autogroup ] && [ -n "$(cat /proc/self/autogroup)" ] && [ "$(ps -o sid= -p $$ | tr -d ' ')" = "$$" ]; then
  echo 10 > /proc/self/autogroup  # only as a session leader: never lower the caller's terminal session
fi
queue=$1
workers=${2:-2}
lock="$queue.lock"
logdir="$queue.logs"
mkdir -p "$logdir"

claim() {  # print the next unclaimed line and mark it started
  flock "$lock" python3 - "$queue" <<'PY'
import sys
path = sys.argv[1]
lines = open(path).read().splitlines()
for i, line in enumerate(lines):
    if line.strip() and not line.lstrip().startswith("#"):
        lines[i] = "#started " + line
        open(path, "w").write("\n".join(lines) + "\n")
        print(line)
        break
PY
}

mark() {  # mark() CMD STATUS
  flock "$lock" python3 - "$queue" "$1" "$2" <<'PY'
import sys
path, cmd, status = sys.argv[1:]
lines = open(path).read().splitlines()
for i, line in enumerate(lines):
    if line == "#started " + cmd:
        lines[i] = f"#{status} " + cmd
        break
open(path, "w").write("\n".join(lines) + "\n")
PY
}

worker() {
  while cmd=$(claim) && [ -n "$cmd" ]; do
    log="$logdir/$(date +%s)-$RANDOM.log"
    echo "[$(date +%T)] worker $1: $cmd (log $log)"
    nice -n 10 bash -c "$cmd" >"$log" 2>&1
    rc=$?
    if [ $rc -eq 0 ]; then mark "$cmd" done; else mark "$cmd" "failed($rc)"; fi
    echo "[$(date +%T)] worker $1: rc=$rc $cmd"
  done
}

for w in $(seq 1 "$workers"); do worker "$w" & done
wait
