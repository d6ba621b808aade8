"""Layer 5, `scoring`: numbers from a run's committed files: rewards of evaluation episodes
(`rewards`), OOD scores of a collected dataset (`ood_scores`, `perturbation_bars`), and the
metrics and statistics they are summarized with (`metrics`).

Imports the layers above it (`common`, `methods`, `measures`, `agents`, `ood`) only.
"""
