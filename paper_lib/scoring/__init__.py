"""Layer 5, `scoring`: numbers from a run's committed files: rewards of evaluation episodes
(`rewards`), OOD scores of a collected dataset (`ood_scores`, `perturbation_bars`), the detection
metrics they are summarized with (`metrics`), and the statistics every interval rests on
(`statistics`: the bootstraps' draws, intervals over seeds and of differences).

Imports the layers above it (`common`, `methods`, `measures`, `agents`, `ood`) only.
"""
