#!/usr/bin/env bash
# Land a run trained outside DVC (by scripts/train_queue.sh): collect its ID/OOD states and evaluation
# episodes with the committed code (a HEAD worktree, so edits in progress in this tree do not leak in),
# copy them back, and record the train, collect and evaluate stages in dvc.lock (`dvc commit`). A run not trained
# with what params.yaml gives it today (paper_lib.pipeline.landing) is refused before anything is written.
#   scripts/land_run.sh ENV METHOD SEED [ENV METHOD SEED ...]
# Then it plays the experiments that take each run once, where it lands (`spawn`, `value_level`: `make reproduce` never
# simulates, and its claims table reads spawn/summary.csv, so they come first).
# Then `git add` the run's checkpoint, dataset, evaluation and dvc.lock, and `make reproduce` to score it.
set -eu
root=$(git rev-parse --show-toplevel)
cd "$root"
py="$root/.venv/bin/python"
# A run's checkpoint, dataset and evaluation paths and its stage names' suffix, from paper_lib.pipeline.layout.
run_paths='import sys
from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.layout import stage_suffix
run, layout = (sys.argv[1], sys.argv[2], int(sys.argv[3])), load_run_config().layout
print(layout.checkpoint_dir(*run), layout.dataset_path(*run), layout.evaluation_path(*run), stage_suffix(*run))'
# A run of an env still under `retraining` was trained with that recipe, but its train stage would be recorded
# against `hyperparameters` (the old runs' recipe): move the entry first, when the env's runs land together.
retraining=" $("$py" -c "from paper_lib.pipeline.config import read_params; print(' '.join(read_params().get('retraining') or {}))") "
args=("$@")
for ((i = 0; i + 2 < ${#args[@]}; i += 3)); do
  case "$retraining" in *" ${args[i]} "*)
    echo "error: params.yaml lists ${args[i]} under \`retraining\`: move retraining.${args[i]} into hyperparameters.${args[i]} (its runs were trained with it) and land all of the env's runs together" >&2
    exit 2 ;;
  esac
done
# Each run must have been trained as params.yaml trains it now (recipe, overrides, budget): DVC will vouch for it.
"$py" -m paper_lib.pipeline.landing "$@" || exit 2
wt=$(mktemp -d /tmp/land_run.XXXXXX)
git worktree add -q --detach "$wt" HEAD
trap 'cd "$root" && git worktree remove --force "$wt"' EXIT
stages=()
while [ $# -ge 3 ]; do
  env_id=$1; method=$2; seed=$3; shift 3
  paths=$("$py" -c "$run_paths" "$env_id" "$method" "$seed")
  read -r ck dataset evaluation suffix <<< "$paths"
  [ -f "$ck/model.zip" ] || { echo "error: $ck/model.zip is missing: train the run first" >&2; exit 2; }
  mkdir -p "$wt/$ck" && cp -r "$ck/." "$wt/$ck/"
  (cd "$wt" && nice -n 5 "$py" -m paper_lib.pipeline.stages collect "$env_id" "$method" "$seed" \
            && nice -n 5 "$py" -m paper_lib.pipeline.run_results evaluate "$env_id" "$method" "$seed")
  for out in "$dataset" "$evaluation"; do
    mkdir -p "$(dirname "$out")" && cp "$wt/$out" "$out"
  done
  for stage in train collect evaluate; do stages+=("$stage@$suffix"); done
  echo "landed $env_id $method seed $seed"
done
# record the stages in one index load (`dvc commit -f` reloads it for every stage: ~8 s each, 6 min for one env)
printf '%s\n' "${stages[@]}" > "$wt.stages"
"$py" "$root/scripts/dvc_record.py" "$wt.stages" && rm -f "$wt.stages"
# the new runs' rows of the spawn and value_level experiments (kept rows: the committed runs are not played again)
PATH="$root/.venv/bin:$PATH" "$root/.venv/bin/dvc" repro --single-item spawn value_level
