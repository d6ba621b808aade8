# Issue 38's production runs (scripts/train_queue.sh QUEUE N), run from a worktree of a commit whose params.yaml has
# the decided recipes (Walker2d and Ant: rl-baselines3-zoo's whole entry at n_envs 4; docs/deviations.md). Resume
# points between machines: scripts/resume_points.sh save TREE / restore REPO TREE. A run whose resume point is
# already at its budget lands at once. Land a whole env's 15 runs together (scripts/land_env.py, then `make
# reproduce`): one recipe per env column. Walker2d's 15 runs and 5 independent members landed on 2026-11-28 (their
# lines are gone), and so did its 12 appendix-E scaling runs (`python -m paper_lib.study.scaling --land TREE` copies in
# each scaling run finished in TREE and trained as params.yaml says, then plays its final evaluation once), and so
# did its five studies (`python -m paper_lib.study.worker --all --land-from sqlite:///TREE/results/paper/studies/studies.db`).
# What follows is Ant, whose baseline seed 0 resumed from the 2M probe Ant-v5/baseline-zoo-n4.
# Landing Ant changes three places of params.yaml in one commit: retraining.Ant-v5 replaces hyperparameters.Ant-v5,
# and the 1e6 cap `total_timesteps: {Ant-v5: 1000000}` goes from `run` and `profiles.paper` (else land_env.py refuses
# every run: "total_timesteps: trained with 10000000, params.yaml gives 1000000"; rehearsed with --dry-run on
# 2026-11-28: baseline seed 0 passed every recipe check once both were changed).
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
# Ant's appendix-E scaling runs under the recipe its 1e7 runs use (200k steps, seed 0): they count once Ant's entry
# moves into `hyperparameters` (until then notebook 10 keeps the printed recipe's runs); land as Walker2d's. Ant's
# five studies follow that move: `python -m paper_lib.study.worker --study ppo-Ant-v5-<method> --sampler-seed 0
# --replace-other-recipe` from a tree at or after it.
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 0 results/paper/scaling/Ant-v5/baseline/w64/seed0 --timesteps 200000 --hp hidden_sizes=[64,64]
.venv/bin/python -m paper_lib.agents.training Ant-v5 baseline 0 results/paper/scaling/Ant-v5/baseline/w128/seed0 --timesteps 200000 --hp hidden_sizes=[128,128]
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 0 results/paper/scaling/Ant-v5/masksembles/w64/seed0 --timesteps 200000 --hp hidden_sizes=[64,64]
.venv/bin/python -m paper_lib.agents.training Ant-v5 masksembles 0 results/paper/scaling/Ant-v5/masksembles/w128/seed0 --timesteps 200000 --hp hidden_sizes=[128,128]
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 0 results/paper/scaling/Ant-v5/mc_dropout/w64/seed0 --timesteps 200000 --hp hidden_sizes=[64,64]
.venv/bin/python -m paper_lib.agents.training Ant-v5 mc_dropout 0 results/paper/scaling/Ant-v5/mc_dropout/w128/seed0 --timesteps 200000 --hp hidden_sizes=[128,128]
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 0 results/paper/scaling/Ant-v5/ensemble/w64/seed0 --timesteps 200000 --hp hidden_sizes=[64,64]
.venv/bin/python -m paper_lib.agents.training Ant-v5 ensemble 0 results/paper/scaling/Ant-v5/ensemble/w128/seed0 --timesteps 200000 --hp hidden_sizes=[128,128]
