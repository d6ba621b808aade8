# Issue 38's production runs (scripts/train_queue.sh QUEUE N), run from a worktree of a commit whose params.yaml has
# the decided recipes (Walker2d and Ant: rl-baselines3-zoo's whole entry at n_envs 4; docs/deviations.md). Resume
# points between machines: scripts/resume_points.sh save --keep-landed TREE / restore REPO TREE. A run whose resume
# point is already at its budget lands at once. Land a whole env's 15 runs together (scripts/land_run.sh, then
# `make reproduce`): one recipe per env column. Walker2d baseline seeds 0 and 1 are the committed probes
# results/recipe_probes/Walker2d-v5/baseline-zoo-n4-128/seed{0,1} (same settings and seeds; copy them in).
# The member methods' seed 0 resume from their 300k probes (results/resume_points/recipe_probes/...-zoo-n4),
# Ant baseline seed 0 from the 2M probe Ant-v5/baseline-zoo-n4.
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 masksembles 0 results/paper/checkpoints/Walker2d-v5/masksembles/seed0
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropout 0 results/paper/checkpoints/Walker2d-v5/mc_dropout/seed0
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropconnect 0 results/paper/checkpoints/Walker2d-v5/mc_dropconnect/seed0
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 ensemble 0 results/paper/checkpoints/Walker2d-v5/ensemble/seed0
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 masksembles 1 results/paper/checkpoints/Walker2d-v5/masksembles/seed1
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropout 1 results/paper/checkpoints/Walker2d-v5/mc_dropout/seed1
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropconnect 1 results/paper/checkpoints/Walker2d-v5/mc_dropconnect/seed1
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 ensemble 1 results/paper/checkpoints/Walker2d-v5/ensemble/seed1
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 2 results/paper/checkpoints/Walker2d-v5/baseline/seed2
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 masksembles 2 results/paper/checkpoints/Walker2d-v5/masksembles/seed2
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropout 2 results/paper/checkpoints/Walker2d-v5/mc_dropout/seed2
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 mc_dropconnect 2 results/paper/checkpoints/Walker2d-v5/mc_dropconnect/seed2
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 ensemble 2 results/paper/checkpoints/Walker2d-v5/ensemble/seed2
# Walker2d's independent-ensemble members under the decided recipe (appendix B.2 rule: a quarter of the steps, 4x the epochs)
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 0 results/paper/independent/checkpoints/Walker2d-v5/baseline/seed0 --timesteps 250000 --hp algo.n_epochs=80
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 1 results/paper/independent/checkpoints/Walker2d-v5/baseline/seed1 --timesteps 250000 --hp algo.n_epochs=80
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 2 results/paper/independent/checkpoints/Walker2d-v5/baseline/seed2 --timesteps 250000 --hp algo.n_epochs=80
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 3 results/paper/independent/checkpoints/Walker2d-v5/baseline/seed3 --timesteps 250000 --hp algo.n_epochs=80
.venv/bin/python -m paper_lib.agents.training Walker2d-v5 baseline 4 results/paper/independent/checkpoints/Walker2d-v5/baseline/seed4 --timesteps 250000 --hp algo.n_epochs=80
# Ant at the paper's 1e7 steps, seed 0 of every method first (the baseline took 9.2 h on one core here, beside another run)
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 0 results/paper/checkpoints/Ant-v5/baseline/seed0
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 0 results/paper/checkpoints/Ant-v5/masksembles/seed0
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 0 results/paper/checkpoints/Ant-v5/mc_dropout/seed0
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropconnect 0 results/paper/checkpoints/Ant-v5/mc_dropconnect/seed0
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 0 results/paper/checkpoints/Ant-v5/ensemble/seed0
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 1 results/paper/checkpoints/Ant-v5/baseline/seed1
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 1 results/paper/checkpoints/Ant-v5/masksembles/seed1
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 1 results/paper/checkpoints/Ant-v5/mc_dropout/seed1
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropconnect 1 results/paper/checkpoints/Ant-v5/mc_dropconnect/seed1
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 1 results/paper/checkpoints/Ant-v5/ensemble/seed1
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 2 results/paper/checkpoints/Ant-v5/baseline/seed2
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 2 results/paper/checkpoints/Ant-v5/masksembles/seed2
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 2 results/paper/checkpoints/Ant-v5/mc_dropout/seed2
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropconnect 2 results/paper/checkpoints/Ant-v5/mc_dropconnect/seed2
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 2 results/paper/checkpoints/Ant-v5/ensemble/seed2
