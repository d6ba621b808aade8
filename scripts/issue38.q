# Issue 38's production runs (scripts/train_queue.sh QUEUE N), run from a worktree of a commit whose params.yaml has
# the decided recipes (Walker2d and Ant: rl-baselines3-zoo's whole entry at n_envs 4; docs/deviations.md). Resume
# points between machines: scripts/resume_points.sh save TREE / restore REPO TREE (a run's `.resume/` folder; a
# study's trials travel in the tree's studies.db). Each env's 15 runs landed together (scripts/land_env.py, then
# `make reproduce`): one recipe per env column. Walker2d's 15 runs and 5 independent members landed on 2026-11-28,
# with its 12 appendix-E scaling runs (`python -m paper_lib.study.scaling --land TREE` copies in each scaling run
# finished in TREE and trained as params.yaml says, then plays its final evaluation once) and its five studies
# (`python -m paper_lib.study.worker --all --land-from sqlite:///TREE/results/paper/studies/studies.db`). Ant's 15
# runs at the paper's 1e7 steps and its 8 scaling runs landed on 2026-11-30 (the baseline's seed 0 had resumed
# from the 2M probe Ant-v5/baseline-zoo-n4), and its five studies, trained again under the landed recipe, the same
# day (the Ensemble's with a second worker of its own sampler seed, docs/study.md). Every line has landed, so the
# queue is empty: scripts/resume_training.sh starts nothing until a later issue adds lines here.
