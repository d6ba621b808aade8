# Issue 67's new seeds (scripts/train_queue.sh QUEUE 1), one queue per core, run from a frozen worktree of a commit
# whose training code is the frozen numerics that made seeds 0-2 (scripts/resume_training.sh sets it up). Resume
# points between machines: scripts/resume_points.sh save TREE / restore REPO TREE. A run lands (its evaluation and
# scores) only after the pre-registration commit (docs/preregistration.md) is in main: issue 66.
# MuJoCo seeds 3 and 4 (5 seeds), the fast envs first so that each env's column completes in turn; Ant (1e7 steps, ~4 h a run) last
# Swimmer-v5, seeds 3-4: all 10 landed (2026-12-05)
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 baseline 3 results/paper/checkpoints/Swimmer-v5/baseline/seed3
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 masksembles 3 results/paper/checkpoints/Swimmer-v5/masksembles/seed3
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 mc_dropout 3 results/paper/checkpoints/Swimmer-v5/mc_dropout/seed3
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 mc_dropconnect 3 results/paper/checkpoints/Swimmer-v5/mc_dropconnect/seed3
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 ensemble 3 results/paper/checkpoints/Swimmer-v5/ensemble/seed3
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 baseline 4 results/paper/checkpoints/Swimmer-v5/baseline/seed4
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 masksembles 4 results/paper/checkpoints/Swimmer-v5/masksembles/seed4
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 mc_dropout 4 results/paper/checkpoints/Swimmer-v5/mc_dropout/seed4
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 mc_dropconnect 4 results/paper/checkpoints/Swimmer-v5/mc_dropconnect/seed4
#done .venv/bin/python -m paper_lib.agents.training Swimmer-v5 ensemble 4 results/paper/checkpoints/Swimmer-v5/ensemble/seed4
# HalfCheetah-v5, seeds 3-4: all 10 landed (2026-12-05)
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 baseline 3 results/paper/checkpoints/HalfCheetah-v5/baseline/seed3
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 masksembles 3 results/paper/checkpoints/HalfCheetah-v5/masksembles/seed3
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 mc_dropout 3 results/paper/checkpoints/HalfCheetah-v5/mc_dropout/seed3
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 mc_dropconnect 3 results/paper/checkpoints/HalfCheetah-v5/mc_dropconnect/seed3
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 ensemble 3 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed3
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 baseline 4 results/paper/checkpoints/HalfCheetah-v5/baseline/seed4
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 masksembles 4 results/paper/checkpoints/HalfCheetah-v5/masksembles/seed4
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 mc_dropout 4 results/paper/checkpoints/HalfCheetah-v5/mc_dropout/seed4
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 mc_dropconnect 4 results/paper/checkpoints/HalfCheetah-v5/mc_dropconnect/seed4
#done .venv/bin/python -m paper_lib.agents.training HalfCheetah-v5 ensemble 4 results/paper/checkpoints/HalfCheetah-v5/ensemble/seed4
# Walker2d-v5, seeds 3-4: seeds 3-4 landed (seed 4 2026-12-06)
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 3 results/paper/checkpoints/Walker2d-v5/baseline/seed3
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 masksembles 3 results/paper/checkpoints/Walker2d-v5/masksembles/seed3
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropout 3 results/paper/checkpoints/Walker2d-v5/mc_dropout/seed3
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropconnect 3 results/paper/checkpoints/Walker2d-v5/mc_dropconnect/seed3
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 ensemble 3 results/paper/checkpoints/Walker2d-v5/ensemble/seed3
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 4 results/paper/checkpoints/Walker2d-v5/baseline/seed4
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 masksembles 4 results/paper/checkpoints/Walker2d-v5/masksembles/seed4
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropout 4 results/paper/checkpoints/Walker2d-v5/mc_dropout/seed4
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropconnect 4 results/paper/checkpoints/Walker2d-v5/mc_dropconnect/seed4
#done .venv/bin/python -m paper_lib.agents.training Walker2d-v5 ensemble 4 results/paper/checkpoints/Walker2d-v5/ensemble/seed4
# Ant-v5, seeds 3-4: baseline and masksembles seed 3 landed (2026-12-07)
#done .venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 3 results/paper/checkpoints/Ant-v5/baseline/seed3
#done .venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 3 results/paper/checkpoints/Ant-v5/masksembles/seed3
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 3 results/paper/checkpoints/Ant-v5/mc_dropout/seed3
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropconnect 3 results/paper/checkpoints/Ant-v5/mc_dropconnect/seed3
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 3 results/paper/checkpoints/Ant-v5/ensemble/seed3
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 4 results/paper/checkpoints/Ant-v5/baseline/seed4
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 4 results/paper/checkpoints/Ant-v5/masksembles/seed4
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 4 results/paper/checkpoints/Ant-v5/mc_dropout/seed4
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropconnect 4 results/paper/checkpoints/Ant-v5/mc_dropconnect/seed4
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 4 results/paper/checkpoints/Ant-v5/ensemble/seed4
