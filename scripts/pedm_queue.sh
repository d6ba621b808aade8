#!/usr/bin/env bash
# Play PEDM's protocol (the `pedm` stage, issue 69) on every MuJoCo run that lacks its output, or whose output was
# played with other `pedm` settings than params.yaml's, one run at a time at low priority, from a worktree at HEAD
# (edits in progress here never reach a run), copying each run's folder back.
#   scripts/pedm_queue.sh [WORKTREE]            default /work/pedm_tree; `touch WORKTREE.stop` ends it after a run
# `touch WORKTREE.hold` while a rebuild reads results/ (notebook 6 reads every pedm folder it finds): the queue goes on
# playing, and copies the runs it finished meanwhile once the file is gone (`rm WORKTREE.hold`).
# Order: HalfCheetah, Swimmer, Ant, Walker2d; within an env seed by seed, so that claim 7 gains whole seeds first.
# Then scripts/record_pedm.sh (run_list, scripts/dvc_record.py with the new `pedm@ENV-METHOD-SEED` stages,
# `dvc repro --single-item --force ood pedm_protocol paper_vs_us`, the README's results, `git add`: docs/pipeline.md).
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=${1:-/work/pedm_tree}
[ -x "$repo/.venv/bin/python" ] || { echo "error: $repo/.venv is missing: run \`make setup\` first" >&2; exit 2; }
if [ ! -e "$tree/.git" ]; then
  git -C "$repo" worktree prune
  git -C "$repo" worktree add -q --detach "$tree" HEAD
  ln -s "$repo/.venv" "$tree/.venv"
fi
runs=$(cd "$repo" && .venv/bin/python - <<'PY'
import json, os, yaml
order = ["HalfCheetah-v5", "Swimmer-v5", "Ant-v5", "Walker2d-v5"]
runs = yaml.safe_load(open("runs.yaml"))["sequence_runs"].values()
wanted = yaml.safe_load(open("params.yaml"))["pedm"]  # a run played with other settings is played again
methods = ["baseline", "masksembles", "mc_dropout", "mc_dropconnect", "ensemble"]
for run in sorted(runs, key=lambda r: (order.index(r["env"]), r["seed"], methods.index(r["method"]))):
    out = f"results/paper/pedm/{run['env']}/{run['method']}/seed{run['seed']}"
    done_file = "metrics.csv" if run["env"] == "Walker2d-v5" else "table2_metrics.csv"
    if os.path.isfile(f"{out}/{done_file}"):
        settings = json.load(open(f"{out}/provenance.json")).get("settings", {})
        if all(settings.get(key) == value for key, value in wanted.items()):
            continue
    print(run["env"], run["method"], run["seed"])
PY
)
pending=()  # finished runs not copied yet: WORKTREE.hold was there when they finished
copy_pending() {
  [ -e "$tree.hold" ] && return 0
  for out in "${pending[@]}"; do
    rm -rf "${repo:?}/$out" && mkdir -p "$(dirname "$repo/$out")" && cp -r "$tree/$out" "$repo/$out"
    echo "[$(date +%T)] copied $out"
  done
  pending=()
}
while read -r env_id method seed; do
  [ -e "$tree.stop" ] && { echo "stop file $tree.stop: ending"; break; }
  out="results/paper/pedm/$env_id/$method/seed$seed"
  echo "[$(date +%T)] pedm $env_id $method $seed"
  if (cd "$tree" && nice -n 10 .venv/bin/python -m paper_lib.pipeline.pedm_stage "$env_id" "$method" "$seed"); then
    pending+=("$out")
    echo "[$(date +%T)] done $env_id $method $seed"
  else
    echo "[$(date +%T)] FAILED $env_id $method $seed"
  fi
  copy_pending
done <<< "$runs"
while [ ${#pending[@]} -gt 0 ]; do  # the last runs wait for the hold to end
  [ -e "$tree.hold" ] && { sleep 5; continue; }
  copy_pending
done
