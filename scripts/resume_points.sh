#!/usr/bin/env bash
# Long runs outlive a machine: commit each unfinished run's latest resume point with the project, and put it
# back on the next machine. A resume point (`.<run>.resume/` beside the run's checkpoint path, paper_lib.agents.training)
# holds the model with its optimizer, the normalizer, the curve so far and the RNG states: well under 1 MB for
# the MuJoCo MLPs.
#   scripts/resume_points.sh save TRAINING_TREE [REPO]     copy the resume points of runs still in progress, and
#                                                          the checkpoints of runs finished but not landed (REPO
#                                                          lacks that model.zip; a checkpoint has no optimizer
#                                                          state: an Atari Ensemble's is 14 MB, its resume point
#                                                          79 MB), into REPO/results/resume_points/, and drop the
#                                                          copies of runs that have landed (the tree's checkpoint
#                                                          was trained to the resume point's step, REPO holds it)
#   scripts/resume_points.sh save --keep-landed TRAINING_TREE [REPO]
#                                                          also keep finished runs' last resume points (a probe
#                                                          to be extended to a larger budget later)
#   scripts/resume_points.sh restore [REPO] TRAINING_TREE  put them back where training resumes from them
# REPO defaults to the repository this script is in. Paths below results/ are kept:
#   results/recipe_probes/Walker2d-v5/x/.seed1.resume/  <->  results/resume_points/recipe_probes/Walker2d-v5/x/seed1/
# Optuna studies training in the tree travel as its whole studies database (a few MB), saved while it holds COMPLETE
# trials the repository's lacks (scripts/studies_resume_point.py):
#   results/paper/studies/studies.db  <->  results/resume_points/paper/studies/studies.db
# A resume point at the step of the copy already in REPO keeps that copy's bytes: a finished run that lands again on
# a new machine rewrites its files (zip timestamps, a few ms more wall time) without training, and committing those
# would add megabytes of history a session for nothing.
set -euo pipefail
here=$(cd "$(dirname "$0")/.." && pwd)
mode=${1:-}
keep_landed=0
if [ "$mode" = save ] && [ "${2:-}" = --keep-landed ]; then keep_landed=1; shift; fi
case "$mode" in
  save) tree=${2:?usage: save TRAINING_TREE [REPO]}; repo=${3:-$here} ;;
  restore) if [ $# -ge 3 ]; then repo=$2; tree=$3; else repo=$here; tree=${2:?usage: restore [REPO] TRAINING_TREE}; fi ;;
  *) echo "usage: $0 save TRAINING_TREE [REPO] | restore [REPO] TRAINING_TREE" >&2; exit 2 ;;
esac
store="$repo/results/resume_points"
[ -d "$tree/results" ] || { echo "error: $tree has no results/ folder: give the training tree's root" >&2; exit 2; }
python=$here/.venv/bin/python; [ -x "$python" ] || python=python3

trained_of() {  # the steps a finished checkpoint was trained for (its config.json); nothing when it cannot be read
  "$python" -c 'import json, sys
try:
    print(json.load(open(sys.argv[1]))["trained_timesteps"])
except Exception:
    pass' "$1" 2> /dev/null || true
}

landed() {  # landed() RUN_FOLDER STATE REL: the checkpoint came from this resume point, and REPO holds the same one
  [ -f "$1/model.zip" ] && cmp -s "$1/model.zip" "$repo/results/$3/model.zip" &&
    [ "$(trained_of "$1/config.json")" = "$(step_of "$2")" ]  # not the older run a retraining will replace
}

finished_here() {  # finished_here RUN_FOLDER STATE: the tree's checkpoint is this resume point's run, finished
  [ -f "$1/model.zip" ] && [ -n "$(trained_of "$1/config.json")" ] && [ "$(trained_of "$1/config.json")" = "$(step_of "$2")" ]
}

step_of() {  # the training step a resume point was saved at (its state.pkl); nothing when it cannot be read
  "$python" -c 'import pickle, sys
try:
    print(pickle.load(open(sys.argv[1], "rb"))["num_timesteps"])
except Exception:
    pass' "$1" 2> /dev/null || true
}

if [ "$mode" = save ]; then
  n=0
  while IFS= read -r -d '' state; do
    resume=$(dirname "$state")                     # .../x/.seed1.resume
    run="$(dirname "$resume")/$(basename "$resume" .resume | sed 's/^\.//')"  # .../x/seed1
    rel=${run#"$tree/results/"}
    if [ $keep_landed = 0 ] && landed "$run" "$state" "$rel"; then
      rm -rf "${store:?}/$rel"                      # landed: its resume point is no longer needed
      continue
    fi
    n=$((n + 1))
    if [ $keep_landed = 0 ] && finished_here "$run" "$state"; then  # finished, not landed: its checkpoint lands it
      if [ -f "$store/$rel/model.zip" ] && [ ! -f "$store/$rel/state.pkl" ] && cmp -s "$run/model.zip" "$store/$rel/model.zip"; then
        echo "kept $rel (finished, as saved before)"; continue
      fi
      mkdir -p "$store/$rel.tmp" && cp -r "$run/." "$store/$rel.tmp/"
      rm -rf "${store:?}/$rel" && mv "$store/$rel.tmp" "$store/$rel"
      echo "saved $rel (finished checkpoint, $(du -sh "$store/$rel" | cut -f1))"; continue
    fi                                              # in progress: its last resume point continues it
    if [ -f "$store/$rel/state.pkl" ]; then
      step=$(step_of "$state")
      if [ -n "$step" ] && [ "$step" = "$(step_of "$store/$rel/state.pkl")" ]; then
        echo "kept $rel (step $step, as saved before)"; continue
      fi
    fi
    mkdir -p "$store/$rel.tmp" && cp -r "$resume/." "$store/$rel.tmp/"
    rm -rf "${store:?}/$rel" && mv "$store/$rel.tmp" "$store/$rel"   # a kill leaves the previous copy
    echo "saved $rel ($(du -sh "$store/$rel" | cut -f1))"
  done < <(find "$tree/results" -path "$store" -prune -o -name state.pkl -path '*/.*.resume/*' -print0)
  while IFS= read -r -d '' config; do  # finished checkpoints saved before: dropped once REPO holds the same model
    saved=$(dirname "$config"); rel=${saved#"$store/"}
    if [ ! -f "$saved/state.pkl" ] && cmp -s "$saved/model.zip" "$repo/results/$rel/model.zip"; then
      rm -rf "${saved:?}"; echo "dropped $rel (landed)"
    fi
  done < <(find "$store" -name config.json -print0 2> /dev/null)
  echo "$n resume point(s) in $store"
  # Optuna studies training in the tree: its studies.db carries their trials (scripts/studies_resume_point.py)
  while IFS= read -r -d '' db; do
    rel=${db#"$tree/results/"}
    "$python" "$here/scripts/studies_resume_point.py" save "$db" "$repo/results/$rel" "$store/$rel"
  done < <(find "$tree/results" \( -path "$store" -o -path "$tree/results/resume_points" \) -prune -o -path '*/studies/studies.db' -print0)
else
  [ -d "$store" ] || { echo "no resume points in $store"; exit 0; }
  while IFS= read -r -d '' state; do
    saved=$(dirname "$state"); rel=${saved#"$store/"}
    if [ -f "$tree/results/$rel/model.zip" ]; then  # a landed probe to extend, or the older run a retraining replaces
      echo "note $rel has a checkpoint: training continues from this resume point and replaces it when it ends"
    fi
    target="$tree/results/$(dirname "$rel")/.$(basename "$rel").resume"
    mkdir -p "$target" && cp -r "$saved/." "$target/"
    echo "restored $rel -> $target"
  done < <(find "$store" -name state.pkl -print0)
  while IFS= read -r -d '' config; do  # finished runs not landed yet: their checkpoint, where training finds it done
    saved=$(dirname "$config"); rel=${saved#"$store/"}
    [ -f "$saved/state.pkl" ] && continue
    target="$tree/results/$rel"
    if [ -f "$target/model.zip" ]; then echo "note $rel: $target already holds a checkpoint, left as it is"; continue; fi
    mkdir -p "$target" && cp -r "$saved/." "$target/"
    echo "restored $rel (finished: land it) -> $target"
  done < <(find "$store" -name config.json -print0)
  while IFS= read -r -d '' db; do  # studies in progress: their database replaces the tree's committed one
    rel=${db#"$store/"}
    mkdir -p "$(dirname "$tree/results/$rel")" && cp "$db" "$tree/results/$rel"
    echo "restored $rel (studies in progress)"
  done < <(find "$store" -path '*/studies/studies.db' -print0)
fi
