"""Record many DVC stages as up to date at once: `dvc commit -f` for a list of stages, one index load.

For a change that moves code without changing what it computes (a module renamed, a dep list rewritten), after
`make verify` has shown the outputs unchanged; and for runs landed from outside DVC (scripts/land_run.sh).
`dvc commit -f STAGE ...` reloads the repo index for every target (about 8 s each here, 45 min for the 320 stages
of the main matrix); this loads it once (2 min).
    python scripts/dvc_record.py STAGES_FILE      # one stage address per line, e.g. score@HalfCheetah-v5-baseline-0
"""

from __future__ import annotations

import sys
import time

from dvc.repo import Repo


def main(path: str) -> None:
    names = [line.strip() for line in open(path) if line.strip()]
    start = time.time()
    repo = Repo(".")
    with repo.lock:
        stages = {stage.addressing: stage for stage in repo.index.stages}
        unknown = sorted(set(names) - set(stages))
        if unknown:
            sys.exit(f"error: {path} names stages dvc.yaml does not have: {unknown[:5]}; check the spelling "
                     "(`dvc stage list`)")
        recorded = []
        for name in names:
            stage = stages[name]
            stage.save(allow_missing=False)  # hashes deps and outs as they are now
            stage.commit(allow_missing=False)
            recorded.append(stage)
        recorded[0].dvcfile.dump_stages(recorded, update_pipeline=False)  # what dvc/repo/commit.py does, once
    print(f"recorded {len(recorded)} stage(s) in {time.time() - start:.0f} s")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
