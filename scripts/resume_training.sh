#!/usr/bin/env bash
# Start or continue issue 38's long training on this machine, from a frozen worktree, both cores, low priority.
#   scripts/resume_training.sh [WORKTREE] [QUEUE_DIR]        defaults: /work/frozen /work/queue
# A machine that still has WORKTREE (the previous session's) keeps it and its resume points, which are newer than
# the committed ones, and its queue file's marks ("#started" lines are queued again: they resume). A new machine
# gets a worktree at HEAD sharing this tree's .venv (later edits here never reach a running training), the committed
# resume points (results/resume_points/, scripts/resume_points.sh: runs' and studies' progress) and a fresh copy of
# scripts/issue38.q, whose lines run in order (all of issue 38's have landed: it is empty now).
# Before stopping: scripts/resume_points.sh save WORKTREE (it keeps the resume points of runs not landed yet, finished
# ones included), and commit results/resume_points.
# NO_START=1 prepares the worktree and the queue and stops before starting the workers.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=${1:-/work/frozen}
queue_dir=${2:-/work/queue}
queue="$queue_dir/issue38.q"
[ -x "$repo/.venv/bin/python" ] || { echo "error: $repo/.venv is missing: run \`make setup\` first" >&2; exit 2; }
if pgrep -f "train_queue.sh $queue" > /dev/null; then
  echo "error: a queue on $queue is already running (pgrep -af train_queue.sh); stop it first" >&2; exit 2
fi

if [ -d "$tree/.git" ] || [ -f "$tree/.git" ]; then
  echo "reusing $tree at $(git -C "$tree" log --oneline -1) with its own resume points"
else
  git -C "$repo" worktree prune
  git -C "$repo" worktree add --detach "$tree" HEAD
  ln -s "$repo/.venv" "$tree/.venv"
  "$repo/scripts/resume_points.sh" restore "$repo" "$tree"
fi

mkdir -p "$queue_dir"
if [ -f "$queue" ]; then
  sed -i 's/^#started //' "$queue"   # killed with the previous machine session: resume them
else
  cp "$repo/scripts/issue38.q" "$queue"
fi
echo "$(grep -c '^\.venv' "$queue") runs queued in $queue, $(grep -c '^#done' "$queue") done"
if [ "${NO_START:-}" = 1 ]; then echo "NO_START=1: not starting the workers"; exit 0; fi
cd "$tree"
setsid nohup bash scripts/train_queue.sh "$queue" 2 >> "$queue_dir/issue38.out" 2>&1 < /dev/null &
sleep 2
for pid in $(pgrep -f "train_queue.sh $queue"); do  # below the foreground's tests and notebooks
  [ -w "/proc/$pid/autogroup" ] && echo 19 > "/proc/$pid/autogroup" || true
done
echo "started: tail -f $queue_dir/issue38.out; logs in $queue.logs/; progress: python scripts/training_progress.py $tree"
