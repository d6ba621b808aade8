#!/usr/bin/env bash
# Record the PEDM-protocol runs that scripts/pedm_queue.sh copied into results/ and rebuild what reads them, in the
# one safe order: hold the queue (it would copy a run in while notebook 6 reads results/, or while files are staged),
# list the runs (runs.yaml's pedm_runs come from the folders present), record their `pedm@...` stages in one index
# load, rebuild Table 2, notebook 14 and the claims, and stage exactly those files. The hold ends with the script:
# what the queue copies afterwards is not staged, so `git commit` (without -a) takes only these runs.
#   scripts/record_pedm.sh [WORKTREE]        default /work/pedm_tree (the queue's), whose WORKTREE.hold it sets
# A run already in dvc.lock whose stage is stale (played with other settings) is refused: play it again, do not
# record it. Then `git commit`.
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
tree=${1:-/work/pedm_tree}
cd "$repo"
py="$repo/.venv/bin/python"
[ -x "$py" ] || { echo "error: $repo/.venv is missing: run \`make setup\` first" >&2; exit 2; }
export PATH="$repo/.venv/bin:$PATH"
held_here=0
if [ ! -e "$tree.hold" ]; then touch "$tree.hold"; held_here=1; fi
list=$(mktemp /tmp/record_pedm.XXXXXX)
trap 'rm -f "$list" "$list.folders"; [ "$held_here" = 1 ] && rm -f "$tree.hold"' EXIT
"$py" -m paper_lib.pipeline.run_list
# the pedm stages runs.yaml lists that dvc.lock has no entry for: the runs played since the last recording
"$py" - "$list" <<'PY'
import sys, yaml
runs = yaml.safe_load(open("runs.yaml"))["pedm_runs"] or {}
locked = yaml.safe_load(open("dvc.lock"))["stages"]
new = [name for name in runs if f"pedm@{name}" not in locked]
open(sys.argv[1], "w").write("".join(f"pedm@{name}\n" for name in new))
open(sys.argv[1] + ".folders", "w").write("".join(
    f"results/paper/pedm/{runs[name]['env']}/{runs[name]['method']}/seed{runs[name]['seed']}\n" for name in new))
print(f"{len(new)} PEDM run(s) to record: {' '.join(new) or '-'}")
PY
[ -s "$list" ] || { echo "nothing to record"; exit 0; }
stale=$(dvc status --json | "$py" -c 'import json, sys; print(" ".join(s for s in json.load(sys.stdin) if s.startswith("pedm@")))')
for name in $stale; do
  grep -qx "$name" "$list" || { echo "error: $name is in dvc.lock but stale (its code, settings or checkpoint changed): play it again (\`dvc repro -s $name\`) rather than record it" >&2; exit 2; }
done
"$py" scripts/dvc_record.py "$list"
nice dvc repro --single-item --force ood pedm_protocol paper_vs_us
"$py" scripts/readme_results.py
mapfile -t folders < "$list.folders"
git add dvc.lock runs.yaml README.md docs/results.md results/paper/tables results/paper/figures results/paper/notebooks \
  "${folders[@]}"
echo "staged ${#folders[@]} run folder(s) and the rebuilt outputs: review \`git diff --cached --stat\`, then \`git commit\`"
