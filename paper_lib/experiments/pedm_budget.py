"""How many epochs PEDM needs on one CPU core: its validation curve per epoch, with wall time (issue 69).

PEDM trains 2000 epochs (``PEDMConfig``), ~16 s an epoch over 45 episodes here: ~9 h a run, 80 MuJoCo runs. This
measures the curve on one committed run to choose a cut (docs/deviations.md, params.yaml's ``pedm``):

    nice -n 5 python -m paper_lib.experiments.pedm_budget HalfCheetah-v5 baseline 0 \
        --episodes 50 10 --epochs 300 300 --out results/paper/pedm/budget_curve.csv
    nice -n 5 python -m paper_lib.experiments.pedm_budget HalfCheetah-v5 baseline 0 --episodes 50 --epochs 120 \
        --probes bm_factor/minor bm_factor/severe ... force_vector/severe --probe-episodes 4 \
        --probe-epochs 10 20 30 40 50 60 70 80 100 120 --out results/paper/pedm/budget_auroc.csv

For each number of ID episodes (the first n of the run's PEDM ID collection, `pedm_collect.play_id`), PEDM is fit
as the stage fits it, and each epoch records its cumulative wall time, the training loss, PEDM's own validation
MSE (members' means on a bootstrap of its held-out episodes) and the MSE on ``--eval-episodes`` further ID episodes
of other seeds, the same for every n (so curves of different n compare on one set). With ``--probes kind/severity
...``, the epochs of ``--probe-epochs`` also record the pooled per-step AUROC of that epoch's weights on test
collections of ``--probe-episodes`` episodes: what the epochs buy in detection, not only in fit.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import torch as th

from paper_lib.common.io import write_text_atomic
from paper_lib.measures.dynamics import PEDMConfig, PEDMDetector, ProbEnsemble
from paper_lib.ood.pedm_collect import CONDITIONS, play_id, play_tests
from paper_lib.pipeline.pedm_stage import load_agent
from paper_lib.pipeline.config import load_run_config
from paper_lib.scoring.metrics import injection_metrics


class TimedPEDM(PEDMDetector):
    """PEDM's fit, unchanged, logging after each epoch its wall time and the MSE on a fixed evaluation set, and at
    ``probe_epochs`` the pooled per-step AUROC of the weights of that epoch on each test collection of ``probes``."""

    def __init__(self, config: PEDMConfig, seed: int, eval_data: dict[str, np.ndarray], log: list[dict],
                 on_epoch: Callable[[], object] | None = None,
                 probes: dict[str, dict[str, np.ndarray]] | None = None, probe_epochs: tuple[int, ...] = ()) -> None:
        super().__init__(config, seed=seed)
        self.eval_data, self.log, self.on_epoch = eval_data, log, on_epoch
        self.probes, self.probe_epochs = probes or {}, set(probe_epochs)

    def fit(self, obs, actions, next_obs, episodes) -> "TimedPEDM":
        self._t0 = time.perf_counter()
        return super().fit(obs, actions, next_obs, episodes)

    def _probe(self, model: ProbEnsemble) -> dict[str, float]:
        """AUROC of this epoch's weights; particles from their own generator, so the fit's draws are untouched."""
        self.model_ = model
        d = len(self.obs_mu_)
        self.eps_ = np.random.default_rng([self.seed, 1]).standard_normal(
            (self.config.ens_size, self.config.n_particles // self.config.ens_size, d)).astype(np.float32)
        out = {}
        for name, data in self.probes.items():
            scores = self.score(data["obs"], data["action"], data["next_obs"])
            out[f"auroc_{name}"] = injection_metrics(scores, data["label"], data["episode"])["auroc"]
        self.model_ = None
        return out

    def _val_mse(self, model: ProbEnsemble, x_val: th.Tensor, y_val: th.Tensor, rng: np.random.Generator) -> float:
        val = super()._val_mse(model, x_val, y_val, rng)  # draws from rng as PEDM's fit does: the same fit
        seconds = time.perf_counter() - self._t0
        x, y = self._standardize(self.eval_data["obs"], self.eval_data["action"], self.eval_data["next_obs"])
        with th.no_grad():
            mean, _ = model(x.expand(self.config.ens_size, -1, -1))
            eval_mse = float(((mean - y) ** 2).mean())
        epoch = len(self.log) + 1
        self.log.append({"epoch": epoch, "seconds": round(seconds, 2), "val_mse": val, "eval_mse": eval_mse,
                         **(self._probe(model) if epoch in self.probe_epochs else {})})
        if self.on_epoch is not None:
            self.on_epoch()
        self._t0 += time.perf_counter() - self._t0 - seconds  # the evaluation's and probes' cost is not PEDM's
        return val


def write_curve(path: Path, table: pd.DataFrame) -> Path:
    """The curve as CSV, 5 significant digits (a few tens of kB for 600 epochs)."""
    return write_text_atomic(path, table.to_csv(index=False, float_format="%.5g", lineterminator="\n"))


def first_episodes(data: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    keep = data["episode"] < n
    return {k: v[keep] for k, v in data.items()}


def budget_curve(cfg, env_id: str, method: str, seed: int, episodes: list[int], epochs: list[int],
                 n_eval: int = 5, out: Path | None = None, probes: tuple[str, ...] = (), probe_episodes: int = 5,
                 probe_epochs: tuple[int, ...] = ()) -> pd.DataFrame:
    """The per-epoch curve of PEDM fit on the first n ID episodes, for each n of ``episodes`` (``epochs`` each);
    ``probes`` ("kind/severity") are test collections of ``probe_episodes`` scored at ``probe_epochs``."""
    th.set_num_threads(1)
    agent = load_agent(cfg.checkpoint_dir(env_id, method, seed), env_id, method, seed)
    data = play_id(agent, env_id, seed, n_episodes=max(episodes))
    eval_data = play_id(agent, env_id, seed + 7919, n_episodes=n_eval)  # other episode seeds than any run's own
    wanted = tuple(tuple(name.split("/")) for name in probes)
    tests = play_tests(agent, env_id, seed + 7919, n_episodes=probe_episodes, conditions=wanted) if probes else {}
    probe_data = {f"{kind}_{severity}": tests[(kind, severity)] for kind, severity in wanted}
    frames: list[pd.DataFrame] = []

    def save(rows: list[dict], n: int) -> pd.DataFrame:
        part = pd.DataFrame(rows).assign(n_id_episodes=n)
        table = pd.concat([*frames, part], ignore_index=True)
        if out is not None:
            write_curve(out, table.assign(env=env_id, method=method, seed=seed))
        return part

    for n, n_epochs in zip(episodes, epochs):
        sub, log = first_episodes(data, n), []
        detector = TimedPEDM(replace(PEDMConfig(), epochs=n_epochs), seed, eval_data, log,
                             on_epoch=lambda: save(log, n), probes=probe_data, probe_epochs=probe_epochs)
        detector.fit(sub["obs"], sub["action"], sub["next_obs"], sub["episode"])
        n_train = int(n * (1 - detector.config.holdout_fraction))
        frames.append(pd.DataFrame(log).assign(
            n_id_episodes=n, n_train_transitions=int(round(len(sub["obs"]) * n_train / n)),
            train_loss=[loss for loss, _ in detector.history_]))
    return pd.concat(frames, ignore_index=True).assign(env=env_id, method=method, seed=seed)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("--episodes", type=int, nargs="+", default=[50, 10])
    parser.add_argument("--epochs", type=int, nargs="+", default=[300, 300])
    parser.add_argument("--eval-episodes", type=int, default=5)
    parser.add_argument("--probes", nargs="*", default=[], help="kind/severity test collections scored for AUROC")
    parser.add_argument("--probe-episodes", type=int, default=5)
    parser.add_argument("--probe-epochs", type=int, nargs="*", default=[])
    parser.add_argument("--out", type=Path, help="default: the profile's pedm/budget_curve.csv (Layout)")
    parser.add_argument("--params", default="params.yaml")
    args = parser.parse_args(argv)
    if len(args.episodes) != len(args.epochs):
        parser.error("give one --epochs value per --episodes value")
    cfg = load_run_config(args.params)
    args.out = args.out or cfg.layout.pedm_budget_curve
    unknown = [name for name in args.probes if tuple(name.split("/")) not in CONDITIONS]
    if unknown:
        parser.error(f"unknown probe(s) {unknown}; use kind/severity of {[f'{k}/{s}' for k, s in CONDITIONS]}")
    table = budget_curve(cfg, args.env_id, args.method, args.seed, args.episodes, args.epochs, args.eval_episodes,
                         args.out, tuple(args.probes), args.probe_episodes, tuple(args.probe_epochs))
    write_curve(args.out, table)
    print(args.out)


if __name__ == "__main__":
    main()
