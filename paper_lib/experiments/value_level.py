"""Is value uncertainty more than a low value? The agent's own value estimate as a confound of value std.

Why this exists: on HalfCheetah our MC Dropout and MC DropConnect agents score the perturbed states
*below* chance with value std (Table 2), where the paper reports 0.40-0.74. A perturbed state is
mostly one where the agent does badly, so its own value estimate V drops; value std then flags those
states only if the members disagree more where V is low. Where they disagree more on high-value
states (std rising with V), a low V hides the OOD state. This module measures, per run, on the
run's own ID/OOD dataset (perturbed or game states):

- ``value_auroc``: AUROC of -V (the member mean), a member-free score that needs no uncertainty;
- ``value_std_auroc``: AUROC of value std on the same states;
- ``id_rank_corr``: Spearman correlation of V and value std on the ID fit states;
- ``value_std_beyond_value_auroc``: AUROC of value std minus its linear trend in V, the trend fitted
  on the ID fit states only (no OOD label is used), so what value std says beyond the value level.

The states and the member samples are the score stage's own (`paper_lib.scoring.ood_scores.score_run`):
the same ID fit/eval split, the same scoring seeds (`scoring_seeds`: ``n_scoring_seeds`` for MC Dropout
and MC DropConnect, one for the deterministic methods) and, under each, the same torch seed per part
(`part_seeds`), with value std computed as scoring computes it (the torch twin, on the same batches).
Each number is computed per scoring seed and the row reports their mean, so ``value_std_auroc`` is the
run's value-std AUROC on the perturbed set of Table 2 (metrics.csv), not a second draw of it.
Notebook 13 (the `value_level` stage) runs it on every run with a dataset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import torch as th
from scipy.stats import spearmanr
from sklearn.metrics import roc_auc_score

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.experiments.kept_rows import fingerprint
from paper_lib.measures.definitions import torch_measures
from paper_lib.measures.detectors import split_fit_eval
from paper_lib.measures.estimates import member_outputs
from paper_lib.methods.policy import MemberActorCriticPolicy
from paper_lib.ood.datasets import StateDataset
from paper_lib.scoring.ood_scores import part_seeds, scoring_seeds

#: The per-run numbers of ``value_level_row`` (after env, method, seed).
COLUMNS = ("n_members", "n_id", "n_ood", "n_scoring_seeds", "value_auroc", "value_std_auroc", "id_rank_corr",
           "value_std_beyond_value_auroc")
AUROCS = ("value_auroc", "value_std_auroc", "value_std_beyond_value_auroc")
#: The numbers computed per scoring seed (the row has their mean).
_PER_SEED = ("value_auroc", "value_std_auroc", "id_rank_corr", "value_std_beyond_value_auroc")
#: `score_dataset`'s batch size: a state's member outputs are the same bits only in the same batches.
_BATCH = 1024


def _observations(data: StateDataset) -> np.ndarray:
    """The states as the policy sees them (after the run's frozen VecNormalize, where it had one)."""
    return data.policy_obs if data.policy_obs is not None else data.states


def _value_and_std(policy, data: StateDataset, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """V (the members' mean value) and value std of every state, with the MC samples of torch seed ``seed``.

    Value std is `torch_measures`' on each batch, as `score_dataset` computes it, so it equals the
    score stage's value_std to the bit (a rank-based AUROC would otherwise move with a last-bit tie).
    """
    values = member_outputs(policy, _observations(data), batch_size=_BATCH, seed=seed).values
    std = [torch_measures(th.from_numpy(np.ascontiguousarray(values[:, start:start + _BATCH])), None, False,
                          ("value_std",))["value_std"].numpy() for start in range(0, values.shape[1], _BATCH)]
    return values.mean(axis=0), np.concatenate(std)


def _one_scoring_seed(policy, parts: dict[str, StateDataset], torch_seed: int) -> dict[str, float]:
    """The value-level numbers under one scoring seed (its `part_seeds`, as the score stage drew them)."""
    seeds = part_seeds(torch_seed)
    value, std = {}, {}
    for name, data in parts.items():
        value[name], std[name] = _value_and_std(policy, data, seeds[name])
    labels = np.r_[np.zeros(len(parts["id"])), np.ones(len(parts["perturbed"]))]

    def auroc(score: dict[str, np.ndarray]) -> float:
        return float(roc_auc_score(labels, np.r_[score["id"], score["perturbed"]]))

    row = {"value_auroc": auroc({name: -v for name, v in value.items()})}
    if np.ptp(std["fit"]) == 0:  # a single network: no value std
        return {**row, "value_std_auroc": np.nan, "id_rank_corr": np.nan, "value_std_beyond_value_auroc": np.nan}
    slope, intercept = np.polyfit(value["fit"], std["fit"], 1)
    beyond = {name: std[name] - (slope * value[name] + intercept) for name in parts}
    return {**row, "value_std_auroc": auroc(std), "id_rank_corr": float(spearmanr(value["fit"], std["fit"]).statistic),
            "value_std_beyond_value_auroc": auroc(beyond)}


def value_level_row(run: Checkpoint, dataset: StateDataset, seed: int, n_scoring_seeds: int = 1) -> dict[str, float]:
    """The run's value-level numbers (see the module docstring); value std columns are NaN for a baseline.

    ``seed`` is the run's seed and ``n_scoring_seeds`` the profile's (params.yaml ``run.n_scoring_seeds``),
    both as the score stage got them: the ID fit/eval split is scoring's (the first draw of
    ``np.random.default_rng(seed)``), an MC method is scored under ``scoring_seeds(seed, n_scoring_seeds)``
    (a deterministic method under the first) with each part's `part_seeds`, and every number is the mean
    over the scoring seeds, so ``value_std_auroc`` equals the run's metrics.csv value_std AUROC (perturbed).
    """
    if isinstance(n_scoring_seeds, bool) or int(n_scoring_seeds) != n_scoring_seeds or n_scoring_seeds < 1:
        raise ValueError(f"n_scoring_seeds={n_scoring_seeds!r}: need a positive integer, the profile's "
                         "run.n_scoring_seeds (as the score stage used).")
    id_data, ood_data = dataset.id_only(), dataset.ood_only()
    if len(id_data) < 4 or len(ood_data) == 0:
        raise ValueError(f"the dataset has {len(id_data)} ID and {len(ood_data)} OOD states; the value-level "
                         "analysis needs both (at least 4 ID states to split); collect the run's dataset again")
    fit_idx, eval_idx = split_fit_eval(len(id_data), np.random.default_rng(seed), groups=id_data.episode)
    parts = {"fit": id_data.subset(fit_idx), "id": id_data.subset(eval_idx), "perturbed": ood_data}
    policy = run.model.policy
    stochastic = isinstance(policy, MemberActorCriticPolicy) and policy.samples_members
    per_seed = pd.DataFrame([_one_scoring_seed(policy, parts, s)
                             for s in scoring_seeds(seed, int(n_scoring_seeds) if stochastic else 1)])
    n_members = policy.n_members if isinstance(policy, MemberActorCriticPolicy) else 1
    return {"n_members": n_members, "n_id": len(parts["id"]), "n_ood": len(parts["perturbed"]),
            "n_scoring_seeds": len(per_seed), **{c: float(per_seed[c].mean()) for c in _PER_SEED}}


#: Part of each run's fingerprint (`kept_rows`): bump it when a change to this module should compute every run again.
ROWS_VERSION = 1


def run_fingerprint(checkpoint_dir: Path, dataset_path: Path, n_scoring_seeds: int) -> str:
    """What a run's row comes from: its checkpoint's model and normalizer, its dataset and the scoring seeds."""
    return fingerprint([Path(checkpoint_dir) / "model.zip", Path(checkpoint_dir) / "vecnormalize.pkl",
                        Path(dataset_path)], {"n_scoring_seeds": n_scoring_seeds, "version": ROWS_VERSION})


def value_level_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per (env, method): the per-run numbers as the mean over seeds, with the number of seeds."""
    numbers = ["value_auroc", "value_std_auroc", "value_std_beyond_value_auroc", "id_rank_corr"]
    cells = rows.groupby(["env", "method"], sort=False)
    return cells[numbers].mean().assign(seeds=cells.size()).reset_index()


def _span(values: pd.Series) -> str:
    """"0.84-0.94", or one number where every value rounds the same."""
    low, high = f"{values.min():.2f}", f"{values.max():.2f}"
    return low if low == high else f"{low}-{high}"


def value_level_reading(table: pd.DataFrame, shift: float = 0.1) -> list[str]:
    """One line per env: how far -V alone goes, and where removing the value trend moves value std by ``shift`` or more."""
    lines = []
    for env_id, cells in table.groupby("env", sort=False):
        best = cells.loc[cells.value_auroc.idxmax()]
        line = (f"**{env_id}**: -V alone reaches AUROC {_span(cells.value_auroc)} "
                f"(best: {best.method} {best.value_auroc:.2f})")
        members = cells.dropna(subset=["value_std_auroc"])
        if len(members):
            top = members.loc[members.value_std_auroc.idxmax()]
            line += f", the best value std {top.method} {top.value_std_auroc:.2f}"
        moved = members[(members.value_std_beyond_value_auroc - members.value_std_auroc).abs() >= shift]
        if len(members) and len(moved):
            line += "; value std, raw -> beyond the value trend: " + ", ".join(
                f"{c.method} {c.value_std_auroc:.2f} -> {c.value_std_beyond_value_auroc:.2f} (ID rank corr. "
                f"{c.id_rank_corr:+.2f})" for c in moved.itertuples())
        elif len(members):
            line += f"; removing the value trend moves no method's value-std AUROC by {shift} or more"
        seeds = sorted(set(cells.seeds))
        lines.append(line + f" ({'/'.join(map(str, seeds))} seed(s) per cell).")
    return lines
