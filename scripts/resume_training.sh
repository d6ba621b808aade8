#!/usr/bin/env bash
# Start or continue the long training on this machine, from a frozen worktree, one worker per queue, low priority.
#   scripts/resume_training.sh [WORKTREE] [QUEUE_DIR]        defaults: /work/frozen /work/queue
# QUEUES names the queue files of scripts/ to run, one worker each (default: issue 67's two, Atari seeds 1-2 on one
# core and MuJoCo seeds 3-4 on the other).
# A machine that still has WORKTREE (the previous session's) keeps it and its resume points, which are newer than
# the committed ones, and its queue file's marks ("#started" lines are queued again: they resume). A new machine
# gets a worktree at HEAD sharing this tree's .venv (later edits here never reach a running training), the committed
# resume points (results/resume_points/, scripts/resume_points.sh: runs' and studies' progress) and a fresh copy of
# each queue file, whose lines run in order (scripts/issue38.q's have all landed: it is empty now).
# Before stopping: scripts/resume_points.sh save WORKTREE (it keeps the resume points of runs not landed yet, finished
# ones included), and commit results/resume_points.
# NO_START=1 prepares the worktree and the queue and stops before starting the workers.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=${1:-/work/frozen}
queue_dir=${2:-/work/queue}
queues=${QUEUES:-"issue67_atari issue67_mujoco"}
[ -x "$repo/.venv/bin/python" ] || { echo "error: $repo/.venv is missing: run \`make setup\` first" >&2; exit 2; }
for name in $queues; do
  [ -f "$repo/scripts/$name.q" ] || { echo "error: no queue file scripts/$name.q (QUEUES='$queues')" >&2; exit 2; }
  if pgrep -f "train_queue.sh $queue_dir/$name.q" > /dev/null; then
    echo "error: a queue on $queue_dir/$name.q is already running (pgrep -af train_queue.sh); stop it first" >&2; exit 2
  fi
done

if [ -d "$tree/.git" ] || [ -f "$tree/.git" ]; then
  echo "reusing $tree at $(git -C "$tree" log --oneline -1) with its own resume points"
else
  git -C "$repo" worktree prune
  git -C "$repo" worktree add --detach "$tree" HEAD
  ln -s "$repo/.venv" "$tree/.venv"
  "$repo/scripts/resume_points.sh" restore "$repo" "$tree"
fi

mkdir -p "$queue_dir"
for name in $queues; do
  queue="$queue_dir/$name.q"
  if [ -f "$queue" ]; then
    sed -i 's/^#started //' "$queue"   # killed with the previous machine session: resume them
  else
    cp "$repo/scripts/$name.q" "$queue"
  fi
  echo "$name: $(grep -c '^\.venv' "$queue") runs queued in $queue, $(grep -c '^#done' "$queue") done"
done
if [ "${NO_START:-}" = 1 ]; then echo "NO_START=1: not starting the workers"; exit 0; fi
cd "$tree"
for name in $queues; do
  queue="$queue_dir/$name.q"
  setsid nohup bash scripts/train_queue.sh "$queue" 1 >> "$queue_dir/$name.out" 2>&1 < /dev/null &
done
sleep 2
for name in $queues; do
  for pid in $(pgrep -f "train_queue.sh $queue_dir/$name.q"); do  # below the foreground's tests and notebooks
    [ -w "/proc/$pid/autogroup" ] && echo 19 > "/proc/$pid/autogroup" || true
  done
done
echo "started: tail -f $queue_dir/*.out; logs in $queue_dir/*.q.logs/; progress: python scripts/training_progress.py $tree"
