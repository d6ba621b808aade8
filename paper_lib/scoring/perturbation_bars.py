"""Uncertainty on perturbed ID states relative to unperturbed ones (paper appendix H bar charts)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.ood.collect import noise_ood_states, pixel_ood_states
from paper_lib.scoring.ood_scores import score_dataset
from paper_lib.ood.datasets import StateDataset
from paper_lib.ood.pixels import PIXEL_PERTURBATIONS

#: Noise magnitudes (multiples of the ID std) shown for vector observations.
NOISE_MAGNITUDES = (1.0, 2.0, 4.0)
MEASURES = ("value_std", "policy_std", "policy_js")


def perturbation_ratios(checkpoint: Checkpoint, dataset: StateDataset, rng: np.random.Generator) -> pd.DataFrame:
    """Mean measure on perturbed ID states / mean on the ID states: one row per (perturbation, measure).

    Images get the paper's pixel perturbations; vector observations get uniform noise (added to the
    raw states, then normalized with the run's saved statistics where it used VecNormalize).
    """
    id_data = dataset.id_only()
    base = score_dataset(checkpoint.model, id_data)
    if id_data.states.ndim > 2:
        variants = {kind: pixel_ood_states(id_data, [kind], rng) for kind in PIXEL_PERTURBATIONS}
    else:
        normalizer = checkpoint.env(1, 0) if checkpoint.vecnormalize_path is not None else None
        variants = {f"noise x{m:g} std": noise_ood_states(id_data, rng, magnitude=m, vecnormalize=normalizer)
                    for m in NOISE_MAGNITUDES}
    rows = []
    for name, perturbed in variants.items():
        scored = score_dataset(checkpoint.model, perturbed)
        for measure in MEASURES:
            if measure in scored:
                rows.append({"perturbation": name, "measure": measure,
                             "ratio": float(scored[measure].mean() / base[measure].mean())})
    return pd.DataFrame(rows)
