# Issue 67's new seeds (scripts/train_queue.sh QUEUE 1), one queue per core, run from a frozen worktree of a commit
# whose training code is the frozen numerics that made seeds 0-2 (scripts/resume_training.sh sets it up). Resume
# points between machines: scripts/resume_points.sh save TREE / restore REPO TREE. A run lands (its evaluation and
# scores) only after the pre-registration commit (docs/preregistration.md) is in main: issue 66.
# Atari seeds 1 and 2 (the paper's 3 seeds), game by game so that each game's column completes in turn
# SeaquestNoFrameskip-v4, seeds 1-2: seed 1 landed (2026-12-05), seed 2 landed (2026-12-07)
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 baseline 1 results/paper/checkpoints/SeaquestNoFrameskip-v4/baseline/seed1
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 masksembles 1 results/paper/checkpoints/SeaquestNoFrameskip-v4/masksembles/seed1
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 mc_dropout 1 results/paper/checkpoints/SeaquestNoFrameskip-v4/mc_dropout/seed1
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 mc_dropconnect 1 results/paper/checkpoints/SeaquestNoFrameskip-v4/mc_dropconnect/seed1
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 ensemble 1 results/paper/checkpoints/SeaquestNoFrameskip-v4/ensemble/seed1
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 baseline 2 results/paper/checkpoints/SeaquestNoFrameskip-v4/baseline/seed2
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 masksembles 2 results/paper/checkpoints/SeaquestNoFrameskip-v4/masksembles/seed2
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 mc_dropout 2 results/paper/checkpoints/SeaquestNoFrameskip-v4/mc_dropout/seed2
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 mc_dropconnect 2 results/paper/checkpoints/SeaquestNoFrameskip-v4/mc_dropconnect/seed2
#done .venv/bin/python -m paper_lib.agents.training SeaquestNoFrameskip-v4 ensemble 2 results/paper/checkpoints/SeaquestNoFrameskip-v4/ensemble/seed2
# MsPacmanNoFrameskip-v4, seeds 1-2: baseline seed 1 landed (2026-12-07), masksembles seed 1 landed (2026-12-08)
#done .venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 baseline 1 results/paper/checkpoints/MsPacmanNoFrameskip-v4/baseline/seed1
#done .venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 masksembles 1 results/paper/checkpoints/MsPacmanNoFrameskip-v4/masksembles/seed1
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 mc_dropout 1 results/paper/checkpoints/MsPacmanNoFrameskip-v4/mc_dropout/seed1
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 mc_dropconnect 1 results/paper/checkpoints/MsPacmanNoFrameskip-v4/mc_dropconnect/seed1
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 ensemble 1 results/paper/checkpoints/MsPacmanNoFrameskip-v4/ensemble/seed1
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 baseline 2 results/paper/checkpoints/MsPacmanNoFrameskip-v4/baseline/seed2
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 masksembles 2 results/paper/checkpoints/MsPacmanNoFrameskip-v4/masksembles/seed2
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 mc_dropout 2 results/paper/checkpoints/MsPacmanNoFrameskip-v4/mc_dropout/seed2
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 mc_dropconnect 2 results/paper/checkpoints/MsPacmanNoFrameskip-v4/mc_dropconnect/seed2
.venv/bin/python -m paper_lib.agents.training MsPacmanNoFrameskip-v4 ensemble 2 results/paper/checkpoints/MsPacmanNoFrameskip-v4/ensemble/seed2
# BerzerkNoFrameskip-v4, seeds 1-2
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 baseline 1 results/paper/checkpoints/BerzerkNoFrameskip-v4/baseline/seed1
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 masksembles 1 results/paper/checkpoints/BerzerkNoFrameskip-v4/masksembles/seed1
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 mc_dropout 1 results/paper/checkpoints/BerzerkNoFrameskip-v4/mc_dropout/seed1
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 mc_dropconnect 1 results/paper/checkpoints/BerzerkNoFrameskip-v4/mc_dropconnect/seed1
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 ensemble 1 results/paper/checkpoints/BerzerkNoFrameskip-v4/ensemble/seed1
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 baseline 2 results/paper/checkpoints/BerzerkNoFrameskip-v4/baseline/seed2
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 masksembles 2 results/paper/checkpoints/BerzerkNoFrameskip-v4/masksembles/seed2
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 mc_dropout 2 results/paper/checkpoints/BerzerkNoFrameskip-v4/mc_dropout/seed2
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 mc_dropconnect 2 results/paper/checkpoints/BerzerkNoFrameskip-v4/mc_dropconnect/seed2
.venv/bin/python -m paper_lib.agents.training BerzerkNoFrameskip-v4 ensemble 2 results/paper/checkpoints/BerzerkNoFrameskip-v4/ensemble/seed2
# SpaceInvadersNoFrameskip-v4, seeds 1-2
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 baseline 1 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/baseline/seed1
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 masksembles 1 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/masksembles/seed1
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 mc_dropout 1 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/mc_dropout/seed1
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 mc_dropconnect 1 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/mc_dropconnect/seed1
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 ensemble 1 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/ensemble/seed1
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 baseline 2 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/baseline/seed2
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 masksembles 2 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/masksembles/seed2
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 mc_dropout 2 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/mc_dropout/seed2
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 mc_dropconnect 2 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/mc_dropconnect/seed2
.venv/bin/python -m paper_lib.agents.training SpaceInvadersNoFrameskip-v4 ensemble 2 results/paper/checkpoints/SpaceInvadersNoFrameskip-v4/ensemble/seed2
