"""Layer 3, `agents`: from an env id and a method to a trained, saved and reloaded agent.

- `envs`: the Gymnasium envs with the paper's wrappers (Atari preprocessing, VecNormalize).
- `factory`: the paper's hyperparameters (params.yaml) and `make_agent` for PPO, A2C and TRPO.
- `training`: one run trained resumably into a checkpoint folder (`python -m paper_lib.agents.training`).
- `checkpoints`: a checkpoint folder read back with its config and normalizer.

Imports `common`, `methods` and `measures` only.
"""
