"""The study around the tables (paper section 5, section 6's two-objective meta-optimization, appendices C and E).

- `config`: params.yaml's `study` section (objective, search space, ablation axes, budgets per profile);
- `space`: search-space entries -> Optuna suggestions -> make_agent arguments;
- `objective`: one trial: train, evaluation reward, noise-OOD AUROC;
- `storage`: Optuna databases with heartbeats (SQLite by default, PostgreSQL to spread workers);
- `worker`: the worker command that any number of processes or machines run on one study;
- `analysis`, `plots`: trials table, Pareto fronts, best configurations, ablations, figures;
- `scaling`: appendix E's width-scaling runs.
"""
