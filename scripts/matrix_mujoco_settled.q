# MuJoCo matrix runs whose recipe is settled (README "Deviations and choices"): baseline and ensemble do not depend
# on the dropout p or the Masksembles scale. Run with  scripts/train_queue.sh <copy of this file> 2  (it runs each line at nice 10);
# commit each finished run with its dataset.
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 0 results/paper/checkpoints/HalfCheetah-v5/baseline/seed0
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 0 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed0
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train Walker2d-v5 ensemble 0 results/paper/checkpoints/Walker2d-v5/ensemble/seed0
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 1 results/paper/checkpoints/HalfCheetah-v5/baseline/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 1 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train Walker2d-v5 baseline 1 results/paper/checkpoints/Walker2d-v5/baseline/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train Walker2d-v5 ensemble 1 results/paper/checkpoints/Walker2d-v5/ensemble/seed1
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 2 results/paper/checkpoints/HalfCheetah-v5/baseline/seed2
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 ensemble 2 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed2
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train Walker2d-v5 baseline 2 results/paper/checkpoints/Walker2d-v5/baseline/seed2
env PAPER_LIB_RESUME_ROOT=/work/resume .venv/bin/python -m paper_lib.train Walker2d-v5 ensemble 2 results/paper/checkpoints/Walker2d-v5/ensemble/seed2
