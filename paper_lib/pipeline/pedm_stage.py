"""PEDM's protocol on one MuJoCo run (issue 69): the `pedm` stage of dvc.yaml.

    python -m paper_lib.pipeline.pedm_stage HalfCheetah-v5 masksembles 0

The run's agent plays its ID training episodes, its held-out ID (threshold) episodes and 20 test episodes of each
of PEDM's 5 kinds x 2 severities (`paper_lib.ood.pedm_collect`); PEDM and the two sequence baselines are fit on the
ID training transitions (`scoring.peer_scores`, PEDM's epochs from params.yaml's ``pedm`` section); every
transition is scored by every agent measure and detector (`scoring.pedm_scores`). Files, in
results/<profile>/pedm/<env>/<method>/seed<s>/:

    steps.npz        every scored step: condition (-1 = held-out ID, else the index into `conditions`), episode,
                     step, label (int8/int16), and every scorer's score (float16 with 8 mantissa bits, SCORE_MASK;
                     ``scorers`` names them) stored as its two byte planes apart (``score_bytes``: half the
                     compressed size of plain float16); `read_steps` gives them back as ``scores`` (scorers x
                     steps): any metric can be recomputed
    metrics.csv      per (scorer, kind, severity): AUROC, AP (aupr_out), FPR@95, the cluster-bootstrap AUROC
                     interval (episodes); kind ``mean``: PEDM's per-severity means (the detection delay and the
                     time-matched AUROC are computed from steps.npz where they are read: `steps_frame`,
                     `scoring.pedm_scores.step_metrics`)
    pedm_fit.csv     PEDM's training curve on this run (train loss, validation MSE per epoch)
    table2_metrics.csv, table2_replicates.npy
                     PEDM on Table 2's states (HalfCheetah, Swimmer, Ant: `ood.transitions.EXACT_ENVS`): the same
                     PEDM scores one simulated transition from each state the `score` stage evaluates in the run's
                     dataset (`scoring.transition_scores`); per OOD set the `score` stage's metric columns and the
                     AUROC bootstrap replicates (row i for row i), as the `sequence_score` stage writes them
    provenance.json  the run, the SHA-256 of its checkpoint files (and of its dataset where Table 2's states are
                     scored), and the settings the stage ran with

Cost (docs/deviations.md): 269k env steps and one PEDM fit (60 epochs) per run, about 12 CPU-min for a Swimmer run
(22 min of wall beside two trainings on 2 cores); about 0.4 MB (a baseline) to 0.9 MB (a member run) of files.
"""

from __future__ import annotations

import io
import json
import sys
import time
import zipfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th

from paper_lib.agents.training import stage_lock
from paper_lib.common.io import atomic_dir, write_json_atomic
from paper_lib.ood.pedm_collect import LoadedAgent
from paper_lib.pipeline.config import RunConfig, read_params
from paper_lib.pipeline.run_cli import run_stage_main
from paper_lib.ood.datasets import StateDataset
from paper_lib.ood.transitions import EXACT_ENVS
from paper_lib.pipeline.layout import stage_suffix
from paper_lib.pipeline.run_results import (CHECKPOINT_INPUTS, PROVENANCE_FILE, _csv, _replicate_matrix,
                                             check_dataset_identity, load_run_dataset, provenance_record,
                                             read_peer_scores, read_score_csv, run_identity)

FILES = ("steps.npz", "metrics.csv", "pedm_fit.csv", PROVENANCE_FILE)
#: The files of PEDM on Table 2's states, written where the env is one of `ood.transitions.EXACT_ENVS`.
TABLE2_FILES = ("table2_metrics.csv", "table2_replicates.npy")
SECTION = "pedm"
#: The per-step scores in steps.npz: float16 with the last 2 of its 10 mantissa bits cleared (8 bits: relative
#: precision 0.4%, a monotone rounding toward zero, so rankings change only by new ties). The metrics in metrics.csv
#: are computed from the full-precision scores; recomputed from steps.npz, the AUROCs of HalfCheetah seed 0 differ by
#: at most 1e-4 (baseline and Masksembles), and a member run's steps.npz (6 scorers) stays under 1 MB (0.92 MB;
#: 1.12 MB with all 10 bits).
SCORE_DTYPE = np.dtype("<f2")
SCORE_MASK = np.uint16(0xFFFC)


@dataclass(frozen=True)
class PEDMSettings:
    """What one run's stage plays and fits; params.yaml's ``pedm`` section sets the first four."""

    epochs: int
    id_episodes: int = 50
    threshold_episodes: int = 5
    test_episodes: int = 20
    n_bootstrap: int = 1000
    max_steps: int | None = None  # tests only: shorter episodes
    injection_step: int | None = None  # tests only: a fixed injection step

    def __post_init__(self) -> None:
        for name in ("epochs", "id_episodes", "threshold_episodes", "test_episodes", "n_bootstrap"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"pedm.{name} must be a positive integer, got {value!r}; fix params.yaml's "
                                 f"`{SECTION}` section")
        if self.id_episodes < 2:
            raise ValueError(f"pedm.id_episodes must be at least 2 (PEDM holds out 10% of them), got {self.id_episodes}")


def read_settings(params_path: str | Path, n_bootstrap: int) -> PEDMSettings:
    """params.yaml's ``pedm`` section (epochs, id_episodes, threshold_episodes, test_episodes), or one error."""
    section = read_params(params_path).get(SECTION)
    if not isinstance(section, dict) or "epochs" not in section:
        raise ValueError(f"{params_path} has no `{SECTION}` section with `epochs`: add it (PEDM's training epochs, "
                         "docs/deviations.md)")
    known = {"epochs", "id_episodes", "threshold_episodes", "test_episodes"}
    unknown = sorted(set(section) - known)
    if unknown:
        raise ValueError(f"{params_path}: unknown key(s) {unknown} in `{SECTION}`; it takes {sorted(known)}")
    return PEDMSettings(**section, n_bootstrap=n_bootstrap)


def load_agent(checkpoint_dir: Path, env_id: str, method: str, seed: int) -> LoadedAgent:
    """A committed run's model and its frozen observation normalizer (no env is built)."""
    from paper_lib.agents.checkpoints import load_checkpoint
    from paper_lib.pipeline.common_states import saved_normalizer

    ckpt = load_checkpoint(checkpoint_dir, env_id, method, seed)
    normalizer = saved_normalizer(ckpt.vecnormalize_path)
    return LoadedAgent(ckpt.model, None if normalizer is None else
                       (lambda obs: normalizer.normalize_obs(obs).astype(np.float32)))


def pedm_dir(cfg: RunConfig, env_id: str, method: str, seed: int) -> Path:
    return cfg.layout.pedm_dir(env_id, method, seed)


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """A compressed .npz with a fixed date on every member, so the same arrays give the same bytes
    (``np.savez_compressed`` stamps each member with the time of writing)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, array in arrays.items():
            member = io.BytesIO()
            np.save(member, np.ascontiguousarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, member.getvalue(), compresslevel=9)
    return buffer.getvalue()


def steps_arrays(steps: pd.DataFrame, conditions: list[tuple[str, str]]) -> dict[str, np.ndarray]:
    """steps.npz's arrays from a `pedm_scores.steps_table`."""
    from paper_lib.scoring.pedm_scores import scorer_names

    names = scorer_names(steps)
    scores = steps[names].to_numpy(SCORE_DTYPE).T  # (scorers, steps): each scorer's series together
    scores = (scores.view(np.uint16) & SCORE_MASK).view(SCORE_DTYPE)  # toward zero: monotone, ties only
    return {"condition": steps["condition"].to_numpy(np.int8), "episode": steps["episode"].to_numpy(np.int16),
            "step": steps["step"].to_numpy(np.int16), "label": steps["label"].to_numpy(np.int8),
            "score_bytes": np.ascontiguousarray(np.moveaxis(scores.view(np.uint8).reshape(*scores.shape, 2), -1, 0)),
            "scorers": np.array(names), "conditions": np.array([f"{kind}/{severity}" for kind, severity in conditions])}


def read_steps(path: str | Path) -> dict[str, np.ndarray]:
    """steps.npz as plain arrays: condition, episode, step, label, scorers, conditions, and ``scores`` (scorers x
    steps, float16) put back together from its byte planes."""
    with np.load(path, allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    planes = arrays.pop("score_bytes", None)
    if planes is None or planes.ndim != 3 or planes.shape[0] != 2 or planes.dtype != np.uint8:
        raise ValueError(f"{path} is not a steps.npz of the `pedm` stage (no (2, scorers, steps) score_bytes); run "
                         "the stage again (`python -m paper_lib.pipeline.pedm_stage ENV METHOD SEED`)")
    arrays["scores"] = np.ascontiguousarray(np.moveaxis(planes, 0, -1)).view(SCORE_DTYPE)[..., 0]
    return arrays


def steps_frame(path: str | Path) -> tuple[pd.DataFrame, list[tuple[str, str]]]:
    """steps.npz as `pedm_scores.steps_table` gave it (columns condition, episode, step, label, one per scorer, as
    float) and its conditions. A score above float16's range was stored as +inf; it is read as the largest float,
    which keeps its rank (above every finite score) and lets the metrics take it."""
    arrays = read_steps(path)
    scores = arrays["scores"].astype(float)
    scores[np.isposinf(scores)] = np.finfo(float).max
    frame = pd.DataFrame({"condition": arrays["condition"].astype(int), "episode": arrays["episode"].astype(int),
                          "step": arrays["step"].astype(int), "label": arrays["label"].astype(int),
                          **dict(zip(arrays["scorers"].tolist(), scores))})
    conditions = [tuple(c.split("/", 1)) for c in arrays["conditions"].tolist()]
    return frame, conditions


def _log(message: str, start: float) -> None:
    print(f"[pedm {time.perf_counter() - start:7.1f} s] {message}", file=sys.stderr, flush=True)


def pedm_files(agent: LoadedAgent, env_id: str, seed: int, settings: PEDMSettings,
               dataset: StateDataset | None = None) -> dict[str, Any]:
    """The stage's work on one loaded agent (`pedm_collect.LoadedAgent`): {file name: DataFrame or arrays}.

    With the run's main `dataset`, the fitted PEDM also scores Table 2's states (TABLE2_FILES), after everything
    else, so the protocol's files are the same with it or without it."""
    from paper_lib.measures.dynamics import PEDMConfig
    from paper_lib.measures.estimates import uncertainty
    from paper_lib.ood.pedm_collect import THRESHOLD_SEED_OFFSET, play_id, play_tests
    from paper_lib.scoring.pedm_scores import protocol_metrics, steps_table
    from paper_lib.scoring.peer_scores import fit_peer_detectors

    start = time.perf_counter()
    th.set_num_threads(1)
    short = dict(max_steps=settings.max_steps)
    id_data = play_id(agent, env_id, seed, settings.id_episodes, **short)
    held_out = play_id(agent, env_id, seed, settings.threshold_episodes, offset=THRESHOLD_SEED_OFFSET, **short)
    tests = play_tests(agent, env_id, seed, settings.test_episodes, injection_step=settings.injection_step, **short)
    _log(f"played {len(id_data['obs']) + len(held_out['obs']) + sum(len(t['obs']) for t in tests.values())} steps", start)
    detectors = fit_peer_detectors(id_data, seed, replace(PEDMConfig(), epochs=settings.epochs))
    _log(f"fit PEDM ({settings.epochs} epochs on {len(id_data['obs'])} transitions) and the sequence baselines", start)

    def measures(next_obs: np.ndarray) -> dict[str, np.ndarray]:
        seen = next_obs if agent.policy_obs is None else agent.policy_obs(next_obs)
        return uncertainty(agent.model, seen, seed=seed)

    steps, conditions = steps_table(held_out, tests, detectors, measures)
    _log(f"scored {len(steps)} steps", start)
    metrics = protocol_metrics(steps, conditions, seed, settings.n_bootstrap)
    _log("metrics", start)
    fit = pd.DataFrame(detectors.pedm.history_, columns=["train_loss", "val_mse"])
    fit.insert(0, "epoch", np.arange(1, len(fit) + 1))
    files = {"steps.npz": steps_arrays(steps, conditions), "metrics.csv": metrics, "pedm_fit.csv": fit}
    if dataset is not None:
        from paper_lib.scoring.transition_scores import score_pedm_on_dataset

        table2 = score_pedm_on_dataset(detectors.pedm, dataset, seed,
                                       lambda obs: agent.model.predict(obs, deterministic=True)[0], agent.policy_obs,
                                       settings.n_bootstrap)  # the run's n_bootstrap, as its `score` stage's
        files |= {"table2_metrics.csv": table2.metrics, "table2_replicates": table2.replicates}
        _log("scored Table 2's states", start)
    return files


def run_pedm(cfg: RunConfig, env_id: str, method: str, seed: int, settings: PEDMSettings) -> Path:
    """The `pedm` stage of one MuJoCo run of the profile: play, fit, score, write FILES at once."""
    from paper_lib.agents.envs import MUJOCO_ENVS

    if env_id not in MUJOCO_ENVS:
        raise ValueError(f"PEDM's protocol is defined for the MuJoCo envs {MUJOCO_ENVS}, got {env_id!r}")
    checkpoint = cfg.checkpoint_dir(env_id, method, seed)
    out = pedm_dir(cfg, env_id, method, seed)
    agent = load_agent(checkpoint, env_id, method, seed)  # a missing or foreign checkpoint: one error, before any work
    identity = run_identity(env_id, method, seed)
    dataset = None
    if env_id in EXACT_ENVS:  # Table 2's states: the run's dataset, checked before any work too
        dataset = load_run_dataset(cfg.dataset_path(env_id, method, seed), env_id, method, seed)
        check_dataset_identity(dataset.metadata, cfg.dataset_path(env_id, method, seed), env_id, method, seed)
    with stage_lock(out, "running PEDM's protocol"):
        provenance = {**provenance_record(identity, _inputs(cfg, env_id, method, seed)), "settings": asdict(settings)}
        files = pedm_files(agent, env_id, seed, settings, dataset)
        tag = dict(identity)
        with atomic_dir(out) as tmp:
            (tmp / "steps.npz").write_bytes(_npz_bytes(files["steps.npz"]))
            (tmp / "metrics.csv").write_text(_csv(files["metrics.csv"].assign(**tag)))
            (tmp / "pedm_fit.csv").write_text(_csv(files["pedm_fit.csv"].assign(**tag)))
            if dataset is not None:
                metrics = files["table2_metrics.csv"]
                (tmp / "table2_metrics.csv").write_text(_csv(metrics.assign(**tag)))
                np.save(tmp / "table2_replicates.npy", _replicate_matrix(metrics, files["table2_replicates"]))
            write_json_atomic(tmp / PROVENANCE_FILE, provenance)
    return out


def _inputs(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Path]:
    """What a run's `pedm` files are made from: its checkpoint, and its dataset where Table 2's states are scored."""
    checkpoint = cfg.checkpoint_dir(env_id, method, seed)
    inputs = {name: checkpoint / name for name in CHECKPOINT_INPUTS}
    return inputs | ({"dataset": cfg.dataset_path(env_id, method, seed)} if env_id in EXACT_ENVS else {})


def read_table2_scores(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> tuple[pd.DataFrame, dict]:
    """PEDM on Table 2's states: (metrics, replicates) of the runs among `runs` whose `pedm` stage scored them
    (`run_results.read_peer_scores`; its inputs are the run's checkpoint and dataset)."""
    return read_peer_scores([run for run in runs if run[0] in EXACT_ENVS], lambda run: pedm_dir(cfg, *run),
                            lambda run: _inputs(cfg, *run),
                            lambda run: f"run it again (`dvc repro -s pedm@{stage_suffix(*run)}`)",
                            metrics_name="table2_metrics.csv", replicates_name="table2_replicates.npy")


def read_metrics(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """Every metrics.csv of `runs` whose `pedm` stage has run, one below the other (each row carries its run's env,
    method and seed). Runs without PEDM-protocol metrics are left out; a cut or foreign file is one error naming the
    stage to run again."""
    from paper_lib.scoring.pedm_scores import METRIC_COLUMNS

    frames = []
    for env_id, method, seed in runs:
        folder = pedm_dir(cfg, env_id, method, seed)
        if not (folder / "metrics.csv").is_file():
            continue
        frames.append(read_score_csv(folder, "metrics.csv", run_identity(env_id, method, seed),
                                     f"run it again (`dvc repro -s pedm@{env_id}-{method}-{seed}`)"))
    if not frames:
        return pd.DataFrame(columns=["scorer", "kind", "severity", *METRIC_COLUMNS, "env", "method", "seed"])
    return pd.concat(frames, ignore_index=True)


def read_run_settings(cfg: RunConfig, env_id: str, method: str, seed: int) -> dict[str, Any]:
    """The settings one run's `pedm` stage ran with (its provenance.json's ``settings``), or one error naming the
    stage to run again."""
    path = pedm_dir(cfg, env_id, method, seed) / PROVENANCE_FILE
    try:
        settings = json.loads(path.read_text()).get("settings")
        if not isinstance(settings, dict):
            raise ValueError("it holds no `settings`")
    except (OSError, UnicodeDecodeError, ValueError, AttributeError) as err:
        raise ValueError(f"{path} is not a readable provenance record of the `pedm` stage ({err}); run it again "
                         f"(`dvc repro -s pedm@{env_id}-{method}-{seed}`)") from None
    return settings


def run_aurocs(cfg: RunConfig, runs: list[tuple[str, str, int]]) -> pd.DataFrame:
    """Claim 7's inputs (`reporting.pedm_claim.RUN_AUROC_COLUMNS`): for each of `runs` whose `pedm` stage has run,
    each scorer's AUROC as PEDM reports it, the mean of its two per-severity means (each the mean over the 5 kinds).
    Runs without PEDM-protocol metrics are left out (the claim says how many it read); a cut or foreign file is one
    error naming the stage to run again (`read_metrics`)."""
    metrics = read_metrics(cfg, runs)
    means = metrics[metrics["kind"] == "mean"].groupby(["env", "method", "seed", "scorer"], sort=False)["auroc"].mean()
    rows = [{"env": env_id, "method": method, "seed": int(seed), "measure": scorer, "auroc": float(auroc)}
            for (env_id, method, seed, scorer), auroc in means.items()]
    return pd.DataFrame(rows, columns=["env", "method", "seed", "measure", "auroc"])


def main(argv: list[str] | None = None) -> None:
    run_stage_main(argv, __doc__.splitlines()[0], lambda cfg, env_id, method, seed, params: run_pedm(
        cfg, env_id, method, seed, read_settings(params, cfg.n_bootstrap)))


if __name__ == "__main__":
    main()
