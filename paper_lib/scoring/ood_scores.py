"""Scoring one run's ID/OOD dataset with every detector and turning the scores into metrics.

Every detector is evaluated on the same states: the ID states held apart from the detector
fitting half, and all OOD states. The member-free detectors (Mahalanobis, kNN) are fitted
on the other ID half, made of other episodes, so they never score a state they were fitted
on, nor one whose episode-mates they were fitted on.

Scoring is seeded from the run's seed: the fit/eval split, the noise OOD states and the
bootstrap (numpy), and the MC methods' per-state samples (torch). A stochastic method
(MC Dropout, MC DropConnect) is scored under several scoring seeds: its metrics are the
means over them, with their spread beside them, so that the sampling noise of the
uncertainty estimate is reported instead of hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.vec_env import VecNormalize

from paper_lib.agents.checkpoints import Checkpoint
from paper_lib.measures.detectors import KNNDetector, MahalanobisDetector, split_fit_eval
from paper_lib.measures.estimates import policy_features, uncertainty
from paper_lib.methods.policy import MemberActorCriticPolicy
from paper_lib.ood.collect import fits_policy, needs_normalization, noise_ood_states, policy_of
from paper_lib.ood.datasets import NO_CONFIG, StateDataset, check_labels
from paper_lib.scoring.metrics import measure_metrics, roc_points
from paper_lib.scoring.statistics import seed_cluster_ci

#: What the metrics tables mean, for their captions.
METRICS_NOTE = ("OOD is the positive class; FPR@95 is the share of ID states flagged when 95% of OOD states are "
                "caught (OpenOOD's definition); the 95% CI of AUROC is a cluster bootstrap that resamples whole ID "
                "episodes and whole OOD conditions, identical configurations (the same maze or physics values "
                "drawn twice) being one (and training seeds first, where a cell pools several)")


@dataclass
class RunScores:
    scores: pd.DataFrame  # one row per evaluated state (first scoring seed): label, ood_set, provenance, detectors
    metrics: pd.DataFrame  # one row per (ood_set, detector): AUROC, AUPR-in/out, FPR@95, detection error, CI, spread
    roc: pd.DataFrame  # ROC points per (ood_set, detector), first scoring seed
    replicates: pd.DataFrame  # cluster-bootstrap AUROC replicates per (ood_set, detector), for CIs over seeds


def scoring_seeds(run_seed: int, n: int) -> list[int]:
    """The torch seeds a run is scored under: fixed by the run's seed, so regenerating repeats them."""
    return [int(np.random.SeedSequence([int(run_seed), 8, j]).generate_state(1)[0]) for j in range(n)]


def part_seeds(torch_seed: int, parts: tuple[str, ...] = ("id", "perturbed", "noise")) -> dict[str, int]:
    """The torch seed of each part under one scoring seed: the ID fit states ("fit"), then `parts` in score_run's order.

    Part i gets SeedSequence([torch_seed, i]). Whoever needs a run's member samples as scoring drew them
    (the value-level analysis) asks here, so the draws are the same states' same masks.
    """
    return {name: int(np.random.SeedSequence([int(torch_seed), i]).generate_state(1)[0])
            for i, name in enumerate(["fit", *parts])}


def score_run(run: Checkpoint | BaseAlgorithm, dataset: StateDataset, seed: int | np.random.Generator,
              n_bootstrap: int, *, n_scoring_seeds: int = 1, noise_magnitude: float = 2.0,
              vecnormalize: VecNormalize | None = None, level: float = 0.95) -> RunScores:
    """All measures and detectors on the physics (or game-state) OOD set and on the noise OOD set.

    ``run`` is a pipeline checkpoint (its saved VecNormalize is used) or any SB3 model (pass
    the ``vecnormalize`` it was trained with, if any). ``seed`` (the run's seed, or a numpy
    Generator made from it) fixes every random choice, torch's MC samples included; a
    stochastic method is scored under ``n_scoring_seeds`` torch seeds. The held-apart ID
    states are scored once per scoring seed and serve as the ID side of both OOD sets.
    """
    if isinstance(seed, np.random.Generator):
        rng, seed = seed, int(seed.integers(2**63 - 1))
    elif isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: give the run's seed (an int >= 0) or np.random.default_rng(seed).")
    else:
        rng = np.random.default_rng(seed)
    if isinstance(n_scoring_seeds, bool) or int(n_scoring_seeds) != n_scoring_seeds or n_scoring_seeds < 1:
        raise ValueError(f"n_scoring_seeds={n_scoring_seeds!r}: need a positive integer (e.g. 5).")
    check_labels(dataset)  # before any work: a label contradicting its source would score OOD states as ID
    model, vecnormalize = _model_and_normalizer(run, vecnormalize, seed % 2**31)
    id_fit, parts = evaluation_parts(dataset, rng, noise_magnitude, vecnormalize)
    stochastic = isinstance(model.policy, MemberActorCriticPolicy) and model.policy.samples_members
    torch_seeds = scoring_seeds(seed, int(n_scoring_seeds) if stochastic else 1)
    obs_scores = _observation_detectors(id_fit, parts)  # no randomness: once for all scoring seeds
    scored = [{name: frame.assign(**obs_scores[name]) for name, frame in _score_parts(model, id_fit, parts, s).items()}
              for s in torch_seeds]  # [scoring seed][part] -> one column per measure and detector
    metric_rows, rocs, replicates = [], [], []
    for ood_set, resample_seed in resample_seeds(rng).items():
        columns = [c for c in scored[0]["id"].columns if c not in _META]
        id_clusters, ood_clusters = bootstrap_clusters(parts, ood_set)
        for c in columns:
            id_s = np.stack([frames["id"][c].to_numpy() for frames in scored])
            ood_s = np.stack([frames[ood_set][c].to_numpy() for frames in scored])
            row, reps = measure_metrics(id_s, ood_s, np.random.default_rng(resample_seed), n_boot=n_bootstrap,
                                        level=level, id_clusters=id_clusters, ood_clusters=ood_clusters)
            metric_rows.append({"ood_set": ood_set, "measure": c, **row})
            replicates.append(pd.DataFrame({"ood_set": ood_set, "measure": c, "replicate": np.arange(reps.size),
                                            "auroc": reps}))
            rocs.append(roc_points(id_s[0], ood_s[0]).assign(measure=c, ood_set=ood_set))
    first = scored[0]
    frames = [pd.concat([first["id"], first[ood_set]], ignore_index=True).assign(ood_set=ood_set)
              for ood_set in ("perturbed", "noise")]
    return RunScores(pd.concat(frames, ignore_index=True), pd.DataFrame(metric_rows)[METRIC_ORDER],
                     pd.concat(rocs, ignore_index=True), pd.concat(replicates, ignore_index=True))


def evaluation_parts(dataset: StateDataset, rng: np.random.Generator, noise_magnitude: float = 2.0,
                     vecnormalize: VecNormalize | None = None) -> tuple[StateDataset, dict[str, StateDataset]]:
    """(ID fit states, {"id", "perturbed", "noise": the states every measure and detector is evaluated on}).

    The first draws of `rng` (the run's seed): the ID episodes split in halves (`split_fit_eval`, whole episodes),
    then the noise added to the held-apart half. Whoever scores a run's dataset with more detectors (the
    `sequence_score` stage) calls this with a fresh rng of the run's seed and gets the very same states.
    """
    id_data, ood_data = dataset.id_only(), dataset.ood_only()
    if len(id_data) == 0 or len(ood_data) == 0:
        raise ValueError(f"the dataset has {len(id_data)} ID and {len(ood_data)} OOD states; scoring needs both.")
    fit_idx, eval_idx = split_fit_eval(len(id_data), rng, groups=id_data.episode)
    id_fit, id_eval = id_data.subset(fit_idx), id_data.subset(eval_idx)
    noise = noise_ood_states(id_eval, rng, magnitude=noise_magnitude, vecnormalize=vecnormalize)
    return id_fit, {"id": id_eval, "perturbed": ood_data, "noise": noise}


def resample_seeds(rng: np.random.Generator) -> dict[str, int]:
    """The cluster-bootstrap seed of each OOD set, drawn after `evaluation_parts` in this order.

    Every measure of an OOD set gets the same cluster resamples: replicate i of two measures comes from the same
    resampled states, so differences between measures of a run are paired (across stages too, where a stage
    replays `evaluation_parts` and then this with the run's seed).
    """
    return {ood_set: int(rng.integers(2**63 - 1)) for ood_set in ("perturbed", "noise")}


def bootstrap_clusters(parts: dict[str, StateDataset], ood_set: str) -> tuple[np.ndarray, np.ndarray]:
    """(ID clusters, OOD clusters) of one OOD set's metrics: noise states keep their ID episode's cluster."""
    return _clusters(parts["id"], "id"), _clusters(parts[ood_set], "id" if ood_set == "noise" else "ood")


_META = ("label", "source", "episode", "step", "config_index", "ood_set")
METRIC_ORDER = ["ood_set", "measure", "auroc", "auroc_ci_low", "auroc_ci_high", "aupr_in", "aupr_out",
                 "fpr_at_95_tpr", "detection_error", "auroc_scoring_std", "auroc_scoring_min", "auroc_scoring_max",
                 "n_scoring_seeds", "ci", "n_id", "n_ood", "n_id_clusters", "n_ood_clusters"]


def _model_and_normalizer(run: Checkpoint | BaseAlgorithm, vecnormalize: VecNormalize | None,
                          seed: int) -> tuple[BaseAlgorithm, VecNormalize | None]:
    """The model, and the observation normalizer it was trained with (a checkpoint's saved one)."""
    if isinstance(run, Checkpoint):
        if vecnormalize is None and run.vecnormalize_path is not None:
            vecnormalize = run.env(1, seed)  # a VecNormalize with the saved, frozen statistics
        return run.model, vecnormalize
    if isinstance(run, BaseAlgorithm):
        return run, vecnormalize
    raise TypeError(f"score_run needs a Checkpoint (load_checkpoint) or an SB3 model, got {type(run).__name__}.")


def _clusters(data: StateDataset, side: str) -> np.ndarray:
    """One cluster label per state: its OOD condition, else its episode.

    A condition is a configuration's parameters without its env seed (`StateDataset.condition_index`):
    MsPacman's 50 configurations are 3 mazes, so 3 clusters, not 50 that the bootstrap would
    wrongly treat as independent. States derived from ID states (noise, pixels) keep their ID
    episode, so with side="id" they share their cluster with the ID states they were made from.
    """
    condition = data.condition_index()
    episode = np.char.add(f"{side}-episode-", data.episode.astype(str))
    labels = np.char.add(f"{side}-condition-", condition.astype(str))
    return np.where(condition != NO_CONFIG, labels, episode)


def _policy_obs(data: StateDataset) -> np.ndarray:
    return data.policy_obs if data.policy_obs is not None else data.states


def _observation_detectors(id_fit: StateDataset, parts: dict[str, StateDataset]) -> dict[str, dict[str, np.ndarray]]:
    """Mahalanobis and 5-NN distance on the observations as the policy sees them, fitted on `id_fit`."""
    fit_obs = _policy_obs(id_fit).reshape(len(id_fit), -1).astype(np.float32)
    detectors = {"knn_obs": KNNDetector().fit(fit_obs)}
    if _policy_obs(id_fit).ndim == 2:  # on raw pixels it would need a (84*84*4)^2 covariance
        detectors["mahalanobis_obs"] = MahalanobisDetector().fit(fit_obs)
    return {name: {det_name: det.score(_policy_obs(data).reshape(len(data), -1).astype(np.float32))
                   for det_name, det in detectors.items()} for name, data in parts.items()}


def _score_parts(model: BaseAlgorithm, id_fit: StateDataset, parts: dict[str, StateDataset],
                 torch_seed: int) -> dict[str, pd.DataFrame]:
    """Every measure and both feature detectors on each part, with the MC samples of one scoring seed.

    Each part gets its own derived seed, so an ID state and the OOD state at the same index
    are not scored with the same masks; the policy features (feature detectors) of a state
    share its member outputs' masks, as one forward pass would.
    """
    seeds = part_seeds(torch_seed, tuple(parts))
    fit_features = policy_features(model.policy, _policy_obs(id_fit), seed=seeds["fit"])
    detectors = {"mahalanobis_features": MahalanobisDetector().fit(fit_features),
                 "knn_features": KNNDetector().fit(fit_features)}
    out = {}
    for name, data in parts.items():
        frame = score_dataset(model, data, seed=seeds[name])
        features = policy_features(model.policy, _policy_obs(data), seed=seeds[name])
        for det_name, det in detectors.items():
            frame[det_name] = det.score(features)
        out[name] = frame
    return out


def summarize_seeds(metrics: pd.DataFrame, replicates: pd.DataFrame, rng: np.random.Generator, n_boot: int = 1000,
                    level: float = 0.95, keys: tuple[str, ...] = ("env", "method")) -> pd.DataFrame:
    """One row per (keys, ood_set, measure) over the training seeds: the table's numbers.

    A table builder: metrics are means over seeds (each already a mean over scoring seeds); the AUROC
    interval is `statistics.seed_cluster_ci` (seeds, then clusters within each), at least Student's t over the
    per-seed AUROCs the row averages and clipped to [0, 1] (issue 66, finding 5); auroc_seed_std is the
    spread over training seeds (NaN with one), auroc_scoring_std the mean spread over scoring
    seeds. With one seed every number equals that run's own.
    """
    group = [*keys, "ood_set", "measure"]
    missing = [c for c in [*group, "seed", "auroc"] if c not in metrics.columns]
    if missing:
        raise ValueError(f"summarize_seeds: metrics lack columns {missing}; tag each run's metrics with "
                         f"{[*keys, 'seed']} first.")
    reps = {key: frame["auroc"].to_numpy() for key, frame in replicates.groupby([*group, "seed"], sort=False)}
    rows = []
    for key, frame in metrics.groupby(group, sort=False):
        per_seed = [reps[(*key, s)] for s in frame["seed"]]
        # the t floor over the AUROCs the row reports (not over the replicates' means, which differ from them by
        # the bootstrap's bias), and an AUROC interval never leaves [0, 1]
        low, high = seed_cluster_ci(per_seed, rng, n_boot=n_boot, level=level, estimates=frame["auroc"].to_numpy())
        low, high = max(low, 0.0), min(high, 1.0)
        row = dict(zip(group, key))
        row.update(n_seeds=len(frame), auroc=frame["auroc"].mean(), auroc_ci_low=low, auroc_ci_high=high,
                   auroc_seed_std=frame["auroc"].std(ddof=1) if len(frame) > 1 else np.nan)
        for column in ("aupr_in", "aupr_out", "fpr_at_95_tpr", "detection_error", "auroc_scoring_std"):
            row[column] = frame[column].mean()
        row.update(auroc_scoring_min=frame["auroc_scoring_min"].min(),
                   auroc_scoring_max=frame["auroc_scoring_max"].max(), n_scoring_seeds=int(frame["n_scoring_seeds"].max()), n_id=frame["n_id"].mean(),
                   n_ood=frame["n_ood"].mean(), n_id_clusters=frame["n_id_clusters"].mean(),
                   n_ood_clusters=frame["n_ood_clusters"].mean())
        rows.append(row)
    return pd.DataFrame(rows)


def score_dataset(model_or_policy: BaseAlgorithm | BasePolicy, dataset: StateDataset,
                  batch_size: int = 1024, seed: int | None = 0) -> pd.DataFrame:
    """One row per state: every uncertainty measure the policy has, plus label and provenance.

    Scores are computed on ``policy_obs`` when the dataset has them (VecNormalize), else on
    the raw states, i.e. always on what the policy saw while acting. ``seed`` fixes the MC
    methods' per-state samples (None: torch's global RNG), so scoring is repeatable.
    """
    policy = policy_of(model_or_policy)
    if not isinstance(dataset, StateDataset):
        raise TypeError(f"dataset must be a StateDataset, got {type(dataset).__name__}.")
    if len(dataset) == 0:
        raise ValueError("the dataset is empty: nothing to score.")
    if dataset.policy_obs is None and needs_normalization(model_or_policy):
        raise ValueError("the model was trained on VecNormalize-d observations but the dataset has no policy_obs: "
                         "collect it with vecnormalize=.")
    obs = dataset.states if dataset.policy_obs is None else dataset.policy_obs
    if not fits_policy(obs.shape[1:], policy):
        raise ValueError(f"the dataset's states have shape {obs.shape[1:]} but the policy takes "
                         f"{policy.observation_space.shape}: score with the model the states were collected for.")
    frame = pd.DataFrame(uncertainty(policy, obs, batch_size=batch_size, seed=seed))
    frame["label"] = dataset.labels
    frame["source"] = dataset.source
    frame["episode"] = dataset.episode
    frame["step"] = dataset.step
    frame["config_index"] = dataset.config_index
    return frame
