# The recipe probes (README, "Deviations and choices"): run with  scripts/train_queue.sh scripts/recipe_probes.q 2
# (the queue script marks lines as it goes: run it on a copy). Summarize with  python -m paper_lib.recipe_probes results/recipe_probes
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 0 results/recipe_probes/HalfCheetah-v5/baseline/seed0 --timesteps 300000
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/recipe_probes/HalfCheetah-v5/masksembles-scale2/seed0 --timesteps 300000 --hp members.masksembles_scale=2.0
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-p0.1/seed0 --timesteps 300000 --hp members.dropout_p=0.1
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-p0.2/seed0 --timesteps 300000 --hp members.dropout_p=0.2
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/recipe_probes/HalfCheetah-v5/masksembles-scale3/seed0 --timesteps 300000 --hp members.masksembles_scale=3.0
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropconnect 0 results/recipe_probes/HalfCheetah-v5/mc_dropconnect-p0.1/seed0 --timesteps 300000 --hp members.dropout_p=0.1
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-p0.05/seed0 --timesteps 300000 --hp members.dropout_p=0.05
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Swimmer-v5 baseline 0 results/recipe_probes/Swimmer-v5/baseline-zoo/seed0
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Swimmer-v5 masksembles 0 results/recipe_probes/Swimmer-v5/masksembles-zoo/seed0
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Ant-v5 baseline 0 results/recipe_probes/Ant-v5/baseline-no-normalization/seed0 --timesteps 1000000
# Session 3: normalization, own assignment, p and scale under normalization, Swimmer/Ant/Walker2d recipe
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 1 results/recipe_probes/HalfCheetah-v5/mc_dropout-p0.05/seed1 --timesteps 300000 --hp members.dropout_p=0.05
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/recipe_probes/HalfCheetah-v5/masksembles-normalize/seed0 --timesteps 300000 --hp normalize_obs=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-normalize/seed0 --timesteps 300000 --hp normalize_obs=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/recipe_probes/HalfCheetah-v5/masksembles-own/seed0 --timesteps 300000 --assignment own
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 baseline 0 results/recipe_probes/HalfCheetah-v5/baseline-normalize/seed0 --timesteps 300000 --hp normalize_obs=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-normalize-p0.05/seed0 --timesteps 300000 --hp members.dropout_p=0.05
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Walker2d-v5 baseline 0 results/recipe_probes/Walker2d-v5/baseline-zoo-policy/seed0 --timesteps 300000 --hp policy.log_std_init=-2.0 --hp policy.ortho_init=false --hp policy.activation_fn=relu
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Walker2d-v5 baseline 0 results/recipe_probes/Walker2d-v5/baseline-gamma0.99-epochs20/seed0 --timesteps 300000 --hp algo.gamma=0.99 --hp algo.n_epochs=20
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Swimmer-v5 masksembles 0 results/recipe_probes/Swimmer-v5/masksembles-zoo-normalize/seed0 --hp normalize_obs=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 0 results/recipe_probes/HalfCheetah-v5/mc_dropout-normalize-p0.2/seed0 --timesteps 300000 --hp members.dropout_p=0.2
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 0 results/recipe_probes/HalfCheetah-v5/masksembles-normalize-scale3/seed0 --timesteps 300000 --hp members.masksembles_scale=3.0
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 1 results/recipe_probes/HalfCheetah-v5/mc_dropout-normalize/seed1 --timesteps 300000
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 masksembles 1 results/recipe_probes/HalfCheetah-v5/masksembles-normalize/seed1 --timesteps 300000
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Walker2d-v5 baseline 0 results/recipe_probes/Walker2d-v5/baseline-normalize-reward/seed0 --timesteps 300000 --hp normalize_reward=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train HalfCheetah-v5 mc_dropout 1 results/recipe_probes/HalfCheetah-v5/mc_dropout-normalize-p0.05/seed1 --timesteps 300000 --hp members.dropout_p=0.05
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Ant-v5 baseline 0 results/recipe_probes/Ant-v5/baseline-normalize/seed0 --timesteps 300000 --hp normalize_obs=true
env PAPER_LIB_RESUME_ROOT=/tmp/resume .venv/bin/python -m paper_lib.train Ant-v5 baseline 0 results/recipe_probes/Ant-v5/baseline-normalize-reward/seed0 --timesteps 300000 --hp normalize_obs=true --hp normalize_reward=true
