"""Train one (env, method, seed) run, resumably, and write its checkpoint folder all or nothing.

Two kinds of artifact:
- the **checkpoint folder** (committed): model.zip with the inference weights only (no optimizer
  moments; loads with plain `PPO.load`), vecnormalize.pkl when the run normalized observations,
  training_curve.csv and config.json (resolved config, package versions, machine, wall time).
  It replaces an old folder in one atomic swap (`paper_lib.common.io.atomic_dir`).
- **resume points** (not committed): every `resume_every` steps, the full training state
  (model with optimizer, normalizer statistics, curve so far, step count, RNG states), so a run
  killed at 90% continues from its last resume point instead of from zero.

    python -m paper_lib.agents.training HalfCheetah-v5 masksembles 0 results/paper/checkpoints/HalfCheetah-v5/masksembles/seed0
    python -m paper_lib.agents.training ... --resume      # continue from the last resume point (the default)

Resume points live beside the checkpoint as `.<name>.resume/`, or under $PAPER_LIB_RESUME_ROOT
(mirroring the checkpoint's path) when that is set, e.g. on a disk that outlives the work tree.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import random
import shlex
import sys
import time
from collections import deque
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

from paper_lib.agents.envs import is_atari, save_normalizer
from paper_lib.agents.factory import HP_OPTIONAL, config_value, make_agent
from paper_lib.common.io import DestinationError, atomic_dir, check_replaceable_dir, write_json_atomic
from paper_lib.common.provenance import machine, package_versions

RESUME_ROOT_ENV = "PAPER_LIB_RESUME_ROOT"
#: Default spacing of resume points, in environment steps.
RESUME_EVERY = 50_000
#: Files that make a folder one of ours: a checkpoint (config.json, model.zip) or a resume point (state.pkl).
OWN_FILES = ("config.json", "model.zip", "state.pkl")


class TrainingCurve(BaseCallback):
    """Per rollout: mean training-episode return (sampled actions, Monitor's last 100 episodes).

    Also writes a resume point at the start of a rollout (after the previous update) once
    `resume_every` steps have passed since the last one.
    """

    def __init__(self, rows: list[dict[str, float]] | None = None, elapsed: float = 0.0,
                 resume_dir: Path | None = None, resume_every: int = RESUME_EVERY,
                 segments: list[dict[str, Any]] | None = None, where: dict[str, Any] | None = None) -> None:
        super().__init__()
        self.rows: list[dict[str, float]] = list(rows or [])
        self.elapsed_before = elapsed
        self.start = time.perf_counter()
        self.resume_dir, self.resume_every = resume_dir, resume_every
        self.last_resume_step: int | None = None
        self.segments_before = list(segments or [])
        self.where = dict(where or {})
        self.first_step: int | None = None

    @property
    def wall_seconds(self) -> float:
        return self.elapsed_before + time.perf_counter() - self.start

    def segments(self, num_timesteps: int) -> list[dict[str, Any]]:
        """Where each stretch of the run trained: a run resumed on another machine has two or more."""
        start = num_timesteps if self.first_step is None else self.first_step
        if num_timesteps <= start:
            return list(self.segments_before)
        return self.segments_before + [{"from_step": int(start), "to_step": int(num_timesteps),
                                        "wall_seconds": time.perf_counter() - self.start, **self.where}]

    def _on_training_start(self) -> None:
        self.first_step = self.num_timesteps

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.last_resume_step is None:
            self.last_resume_step = self.num_timesteps
        if self.resume_dir is not None and self.num_timesteps - self.last_resume_step >= self.resume_every:
            save_resume_point(self.model, self.resume_dir, self.rows, self.wall_seconds,
                              self.segments(self.num_timesteps))
            self.last_resume_step = self.num_timesteps

    def _on_rollout_end(self) -> None:
        episodes = self.model.ep_info_buffer
        self.rows.append({
            "timesteps": self.num_timesteps,
            "reward": float(np.mean([e["r"] for e in episodes])) if episodes else float("nan"),
            "episode_length": float(np.mean([e["l"] for e in episodes])) if episodes else float("nan"),
            # mean reward per env step of this rollout: defined even before any episode has ended
            "step_reward": float(np.mean(self.model.rollout_buffer.rewards)),
            "wall_seconds": self.wall_seconds,
        })


def resume_dir_for(out_dir: str | Path) -> Path:
    """Where the resume points of the run whose checkpoint goes to `out_dir` live."""
    out_dir = Path(out_dir)
    root = os.environ.get(RESUME_ROOT_ENV)
    if root:
        return Path(root) / Path(os.path.abspath(out_dir)).relative_to("/")
    return out_dir.parent / f".{out_dir.name}.resume"


def save_resume_point(model: BaseAlgorithm, folder: Path, rows: list[dict[str, float]], wall_seconds: float,
                      segments: list[dict[str, Any]] | None = None) -> None:
    """The full training state, swapped in atomically: a kill leaves the previous resume point."""
    with atomic_dir(folder) as tmp:
        model.save(tmp / "model.zip")  # includes the optimizer state
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:
            save_normalizer(normalizer, tmp / "vecnormalize.pkl", model.paper_lib_config["env_id"])
        state = {"num_timesteps": model.num_timesteps, "n_updates": getattr(model, "_n_updates", 0),
                 "ep_info_buffer": list(model.ep_info_buffer or []), "rows": rows, "wall_seconds": wall_seconds,
                 "segments": segments or [],
                 "rng": {"torch": th.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()},
                 "config": getattr(model, "paper_lib_config", None)}
        with open(tmp / "state.pkl", "wb") as f:
            pickle.dump(state, f)


#: What makes two trainings the same run: a resume point or a finished checkpoint made with other values is another run.
RECIPE_KEYS = ("algo", "method", "env_id", "seed", "n_members", "dropout_p", "masksembles_scale", "assignment",
               "hidden_sizes", "policy", "normalize_obs", "normalize_reward", "algo_kwargs", "n_envs")


def load_resume_point(model: BaseAlgorithm, folder: Path) -> dict[str, Any]:
    """Restore weights, optimizer, normalizer, counters and RNG states into a freshly built `model`.

    The envs themselves restart their episodes (SB3 does not save env state), which is the one
    difference from an uninterrupted run.
    """
    try:
        with open(folder / "state.pkl", "rb") as f:
            state = pickle.load(f)
        saved_config = state.get("config")
        if saved_config is not None:
            for key in RECIPE_KEYS:
                saved, now = (config_value(c, key) for c in (saved_config, model.paper_lib_config))
                if saved != now:
                    raise ValueError(f"resume point {folder} was trained with {key}={saved!r}, "
                                     f"this run has {now!r}; delete {folder} to start "
                                     "afresh or run with the settings it was made with")
        model.set_parameters(str(folder / "model.zip"), exact_match=True, device=model.device)
    except (OSError, pickle.UnpicklingError, EOFError, KeyError) as err:
        raise ValueError(f"resume point {folder} is unreadable ({type(err).__name__}: {err}); "
                         f"delete it to start the run afresh") from err
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        with open(folder / "vecnormalize.pkl", "rb") as f:
            saved = pickle.load(f)
        normalizer.obs_rms, normalizer.ret_rms = saved.obs_rms, saved.ret_rms
    model.num_timesteps = state["num_timesteps"]
    model._n_updates = state["n_updates"]
    model.ep_info_buffer = deque(state["ep_info_buffer"], maxlen=model._stats_window_size)
    model.ep_success_buffer = deque(maxlen=model._stats_window_size)
    th.set_rng_state(state["rng"]["torch"])
    np.random.set_state(state["rng"]["numpy"])
    random.setstate(state["rng"]["python"])
    return state


def strip_training_state(model: BaseAlgorithm) -> None:
    """Drop the optimizer's moments before the committed save: inference needs only the weights.

    A fresh optimizer of the same class keeps `PPO.load` working; Adam's moments are about two
    thirds of a full checkpoint's size.
    """
    policy = model.policy
    policy.optimizer = policy.optimizer_class(policy.parameters(), lr=policy.optimizer.param_groups[0]["lr"],
                                              **policy.optimizer_kwargs)


def store_inference_weights(model: BaseAlgorithm) -> str:
    """Cast an image policy to float16 for the committed save; MLPs stay float32. Returns the dtype's name.

    A Nature CNN has about 1.7M parameters (four in an ensemble), so Atari checkpoints are the bulk of the
    results tree; float16 halves them. `PPO.load` builds a float32 policy and `load_state_dict` copies the
    float16 values in, so the committed agent is the trained one with its weights rounded to float16
    (relative error below 5e-4), and every evaluation, dataset and score is computed with that agent.
    The resume point, saved before this, keeps the float32 training state.
    """
    if not is_atari(model.paper_lib_config["env_id"]):
        return "float32"
    model.policy.half()
    return "float16"


def gpu_name(device: th.device) -> str | None:
    """The accelerator a run trained on (its numbers differ from a CPU run's of the same seed), or None."""
    return th.cuda.get_device_name(device) if device.type == "cuda" else None


def check_budget(total_timesteps: Any) -> int:
    """A training budget is a positive whole number of steps."""
    if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, (int, np.integer)) or total_timesteps <= 0:
        raise ValueError(f"total_timesteps must be a positive integer, got {total_timesteps!r}; "
                         "give the number of environment steps, e.g. 1000000")
    return int(total_timesteps)


def check_run_folder(folder: Path, what: str) -> None:
    """Training replaces `folder` whole at its end: refuse a file there, or someone else's folder, before training."""
    check_replaceable_dir(folder, what)
    if folder.is_dir() and any(folder.iterdir()) and not any((folder / name).is_file() for name in OWN_FILES):
        raise DestinationError(f"{what} {folder} holds files but no checkpoint or resume point (none of "
                               f"{', '.join(OWN_FILES)}), and training would replace it whole; give a new or empty "
                               "folder (it was left as it is)")


IDENTITY_KEYS = ("algo", "env_id", "method", "seed")


def _identity(algo: str, env_id: str, method: str, seed: int) -> str:
    return f"{algo} {env_id} {method} seed {seed}"


def check_same_run(out_dir: Path, algo: str, env_id: str, method: str, seed: int) -> None:
    """A folder holding another run's finished checkpoint (any algorithm, env, method or seed) is refused, naming
    both: training would replace it whole, and a committed checkpoint has no resume point to come back from."""
    try:
        found = json.loads((out_dir / "config.json").read_text())
    except (OSError, ValueError):
        return
    if not isinstance(found, dict) or not all(key in found for key in IDENTITY_KEYS):
        return
    theirs = tuple(found[key] for key in IDENTITY_KEYS)
    if theirs != (algo, env_id, method, seed):
        raise DestinationError(f"{out_dir} holds the finished run {_identity(*theirs)}; training "
                               f"{_identity(algo, env_id, method, seed)} there would replace it. Give this run its "
                               "own folder (the other was left as it is)")


@contextmanager
def run_lock(out_dir: Path, doing: str = "training",
             fix: str = "wait for it to finish or give this run another folder") -> Iterator[Path]:
    """One writer per run output (a checkpoint folder, a dataset, an evaluation, a scores folder): an OS file lock
    beside it (`.<name>.lock`), held while `doing` and dropped by the kernel if the process dies, so a second writer
    of the same output stops at once instead of racing (the last to finish would replace the other's files)."""
    from filelock import FileLock, Timeout

    out_dir.parent.mkdir(parents=True, exist_ok=True)
    path = out_dir.parent / f".{out_dir.name}.lock"
    lock = FileLock(path, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise DestinationError(f"another process is {doing} into {out_dir} (it holds {path}); {fix} "
                               "(nothing was changed)") from None
    try:
        yield path
    finally:
        # The name goes while the lock is still held: a process that opened the old file meanwhile gets its lock
        # only after this, sees the file unlinked (filelock checks st_nlink) and retries on the name, so two holders
        # never coexist. Unlinking after the release would let it lock the orphan while a third locks a new file.
        # A killed holder's file stays (results/**/.*.lock is git-ignored); the kernel dropped its lock.
        path.unlink(missing_ok=True)
        lock.release()


def stage_lock(out: Path, doing: str) -> AbstractContextManager[Path]:
    """The run lock of a per-run pipeline stage's output (`run_lock`): a second process writing the same run's dataset,
    evaluation or scores stops at once, naming the output the first one holds."""
    return run_lock(out, doing, "wait for it to finish: each run's stage runs in one process at a time")


def finished_budget(out_dir: Path) -> int | None:
    """The budget (total_timesteps) of the finished run in `out_dir`, or None where there is none to read."""
    try:
        budget = json.loads((out_dir / "config.json").read_text()).get("total_timesteps")
    except (OSError, ValueError, AttributeError):
        return None
    return budget if isinstance(budget, int) and not isinstance(budget, bool) else None


def check_finished_budget(out_dir: Path, steps: int) -> None:
    """A resumed run asked for fewer steps than the finished run in `out_dir` would replace it with a smaller one."""
    budget = finished_budget(out_dir)
    if budget is not None and budget > steps:
        raise ValueError(f"{out_dir} holds a finished run of {budget} steps, asked {steps}; use a new folder, or "
                         "--no-resume (resume=False) to train a new run of the smaller budget in its place")


def already_finished(out_dir: Path, config: dict[str, Any], steps: int) -> bool:
    """Whether `out_dir` holds this very run (`config`'s recipe) finished at `steps`: resuming it has nothing left to
    do, and training it again would only replace a finished checkpoint (a landed one, say) with a retrained copy."""
    try:
        saved = json.loads((out_dir / "config.json").read_text())
    except (OSError, ValueError):
        return False
    return ((out_dir / "model.zip").is_file() and isinstance(saved, dict) and saved.get("total_timesteps") == steps
            and (saved.get("trained_timesteps") or 0) >= steps
            and all(config_value(saved, key) == json.loads(json.dumps(config_value(config, key), default=str))
                    for key in RECIPE_KEYS))  # as config.json holds it: tuples read back as lists


def check_resume_budget(model: BaseAlgorithm, resume_dir: Path, resumed_from: int, steps: int) -> None:
    """A resume point past the end of this budget would be exported as it is, labelled with the smaller budget."""
    rollout = getattr(model, "n_steps", 1) * model.n_envs
    stop = -(-steps // rollout) * rollout  # a run of `steps` ends at the first whole rollout at or after it
    if resumed_from > stop:
        raise ValueError(f"the resume point {resume_dir} holds {resumed_from} steps, asked {steps} (a run of that "
                         f"budget stops at {stop}); use a new folder, or --no-resume (resume=False) to train afresh")


def train_run(env_id: str, method: str, seed: int, out_dir: str | Path, algo: str = "ppo",
              total_timesteps: int | None = None, agent_kwargs: dict[str, Any] | None = None,
              torch_threads: int = 1, progress_bar: bool = False, resume: bool = True,
              resume_every: int = RESUME_EVERY, tensorboard: bool = False) -> Path:
    """Train (continuing from the last resume point if `resume`) and write the checkpoint folder.

    The destination is checked first (ValueError): a file or a foreign folder at `out_dir`, another run's
    finished checkpoint there, a second training into the same folder (`run_lock`), or, when resuming, a run there
    already past this budget, is refused before any training.
    """
    out_dir = Path(out_dir)
    check_run_folder(out_dir, "checkpoint folder")
    check_same_run(out_dir, algo, env_id, method, seed)
    with run_lock(out_dir):
        return _train_locked(env_id, method, seed, out_dir, algo, total_timesteps, agent_kwargs, torch_threads,
                             progress_bar, resume, resume_every, tensorboard)


def _train_locked(env_id: str, method: str, seed: int, out_dir: Path, algo: str, total_timesteps: int | None,
                  agent_kwargs: dict[str, Any] | None, torch_threads: int, progress_bar: bool, resume: bool,
                  resume_every: int, tensorboard: bool) -> Path:
    """`train_run` once this process holds the run folder's lock."""
    th.set_num_threads(torch_threads)
    resume_dir = resume_dir_for(out_dir)
    check_run_folder(resume_dir, "resume point folder")
    agent_kwargs = dict(agent_kwargs or {})
    if tensorboard:
        agent_kwargs.setdefault("tensorboard_log", str(resume_dir.parent / f".{out_dir.name}.tensorboard"))
    model = make_agent(algo, method, env_id, seed, **agent_kwargs)
    steps = check_budget(total_timesteps if total_timesteps is not None else model.paper_lib_config["total_timesteps"])
    rows, elapsed, resumed_from, segments = [], 0.0, 0, []
    if resume:
        check_finished_budget(out_dir, steps)
    if resume and not (resume_dir / "state.pkl").is_file() and already_finished(out_dir, model.paper_lib_config, steps):
        print(f"{out_dir} already holds this run, finished at {steps} steps: nothing to do (--no-resume trains it "
              "again)", file=sys.stderr)
        return out_dir
    if resume and (resume_dir / "state.pkl").is_file():
        state = load_resume_point(model, resume_dir)
        rows, elapsed, resumed_from = state["rows"], state["wall_seconds"], state["num_timesteps"]
        check_resume_budget(model, resume_dir, resumed_from, steps)
        segments = state.get("segments") or [{"from_step": 0, "to_step": resumed_from, "device": "not recorded"}]
        print(f"resuming {env_id} {method} seed {seed} from step {resumed_from} ({resume_dir})", file=sys.stderr)
    where = {"device": str(model.device), "gpu": gpu_name(model.device),
             "env_processes": bool(agent_kwargs.get("env_processes", False)), "torch_threads": torch_threads,
             "platform": machine()["platform"]}
    curve = TrainingCurve(rows, elapsed, resume_dir, resume_every, segments, where)
    if resumed_from < steps:
        model.learn(steps - resumed_from, callback=curve, progress_bar=progress_bar, reset_num_timesteps=resumed_from == 0)
    config = {**model.paper_lib_config, "total_timesteps": steps, "trained_timesteps": int(model.num_timesteps),
              "wall_seconds": curve.wall_seconds, "resumed_from": resumed_from or None, "torch_threads": torch_threads,
              "device": where["device"], "gpu": where["gpu"], "env_processes": where["env_processes"],
              "segments": curve.segments(model.num_timesteps), "versions": package_versions(), "machine": machine()}
    if model.num_timesteps >= steps and resume:  # a full resume point first: the export below drops the optimizer
        save_resume_point(model, resume_dir, curve.rows, curve.wall_seconds, config["segments"])
    strip_training_state(model)
    config["weights_dtype"] = store_inference_weights(model)
    with atomic_dir(out_dir) as tmp:
        model.save(tmp / "model.zip")
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:
            save_normalizer(normalizer, tmp / "vecnormalize.pkl", model.paper_lib_config["env_id"])
        pd.DataFrame(curve.rows).to_csv(tmp / "training_curve.csv", index=False)
        write_json_atomic(tmp / "config.json", config)
    return out_dir


def hp_flags(overrides: dict[str, Any]) -> list[str]:
    """Algorithm overrides as this module's `--hp algo.KEY=VALUE` edits (values in YAML/JSON form)."""
    return [f"--hp {shlex.quote(f'algo.{key}={json.dumps(value)}')}" for key, value in overrides.items()]


def train_command(args: list[str], resume_root: str | None = None, python: str = ".venv/bin/python") -> str:
    """The shell line that trains one run (`python -m paper_lib.agents.training ARGS`), resumable under `resume_root`."""
    prefix = [f"env PAPER_LIB_RESUME_ROOT={shlex.quote(resume_root)}"] if resume_root else []
    return " ".join(prefix + [python, "-m", "paper_lib.agents.training"] + args)


def apply_hp_edits(hp: dict[str, Any], edits: list[str]) -> dict[str, Any]:
    """`KEY=VALUE` edits of a hyperparameter entry; dotted keys reach nested settings, values are YAML.

    For recipe probes, e.g. `normalize_obs=true`, `policy.activation_fn=tanh`, `members.dropout_p=0.2`.
    """
    import copy

    import yaml

    hp = copy.deepcopy(hp)
    for edit in edits:
        key, sep, text = edit.partition("=")
        if not sep or not key:
            raise ValueError(f"--hp {edit!r}: write KEY=VALUE, e.g. --hp members.dropout_p=0.2")
        *parents, leaf = key.split(".")
        node = hp
        for name in parents:
            if not isinstance(node.get(name), dict):
                raise ValueError(f"--hp {edit!r}: {name!r} is not a section of the hyperparameters; "
                                 f"sections: {sorted(k for k, v in node.items() if isinstance(v, dict))}")
            node = node[name]
        if leaf not in node and not (not parents and leaf in HP_OPTIONAL):  # e.g. normalize_reward=true
            raise ValueError(f"--hp {edit!r}: unknown setting {leaf!r}; known here: {sorted(node)}")
        node[leaf] = yaml.safe_load(text)
    return hp


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("env_id")
    parser.add_argument("method")
    parser.add_argument("seed", type=int)
    parser.add_argument("out_dir")
    parser.add_argument("--algo", default="ppo")
    parser.add_argument("--timesteps", type=int, default=None, help="training steps (default: the env's budget)")
    parser.add_argument("--assignment", default="shared")
    parser.add_argument("--hp", action="append", default=[], metavar="KEY=VALUE",
                        help="edit the env's hyperparameters, e.g. --hp members.dropout_p=0.2 (repeatable)")
    parser.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                        help="continue from the last resume point if there is one (default: yes)")
    parser.add_argument("--resume-every", type=int, default=RESUME_EVERY, help="steps between resume points")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--device", default="cpu",
                        help="torch device of the networks, e.g. cuda on a lent GPU machine (default: cpu)")
    parser.add_argument("--env-processes", action="store_true",
                        help="step the envs in subprocesses (same transitions; faster with many cores and a GPU)")
    parser.add_argument("--tensorboard", action="store_true", help="write TensorBoard logs beside the resume point")
    parser.add_argument("--progress-bar", action="store_true")
    args = parser.parse_args(argv)
    try:
        if args.timesteps is not None:
            check_budget(args.timesteps)
        if args.resume_every <= 0:
            raise ValueError(f"--resume-every must be a positive number of steps, got {args.resume_every}")
        if args.threads <= 0:
            raise ValueError(f"--threads must be a positive number of torch threads, got {args.threads}")
        try:
            th.device(args.device)
        except RuntimeError:
            raise ValueError(f"--device must be a torch device such as cpu or cuda, got {args.device!r}") from None
        agent_kwargs: dict[str, Any] = {"assignment": args.assignment, "device": args.device,
                                        "env_processes": args.env_processes}
        if args.hp:
            from paper_lib.agents.factory import paper_hyperparameters

            agent_kwargs["hyperparameters"] = apply_hp_edits(paper_hyperparameters(args.env_id), args.hp)
        train_run(args.env_id, args.method, args.seed, args.out_dir, algo=args.algo, total_timesteps=args.timesteps,
                  agent_kwargs=agent_kwargs, torch_threads=args.threads,
                  progress_bar=args.progress_bar, resume=args.resume, resume_every=args.resume_every,
                  tensorboard=args.tensorboard)
    except ValueError as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    main()
