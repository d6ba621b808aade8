# MuJoCo matrix runs whose recipe is settled (README "Deviations and choices"). Run with
#   scripts/train_queue.sh <copy of this file> 2      (each line at nice 10; commit each finished run with its dataset)
# Settled: HalfCheetah-v5 with observation normalization, baseline and ensemble (they do not depend on the dropout p or
# the Masksembles scale). Done and committed: HalfCheetah baseline seed 0 (normalized), Swimmer baseline seed 0,
# Walker2d baseline and ensemble seed 0.
# Held until probes decide: Walker2d (its baseline reaches 630 against the paper's 2959: probes of the zoo policy
# settings and of gamma 0.99 / 20 epochs are queued), Swimmer and Ant (normalization), every member method (p, scale).
# Tip: run the queue from a git worktree of a fixed commit (git worktree add ../train_tree HEAD) with absolute output
# paths, so that edits to the working tree never reach a running training job.
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 1 results/paper/checkpoints/HalfCheetah-v5/baseline/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 2 results/paper/checkpoints/HalfCheetah-v5/baseline/seed2
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 0 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed0
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 1 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 2 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed2
