"""What notebooks 00 and 07 draw from simulation, recorded once: the example states' frames and the quickstart's
episode with its change of gravity (`paper_lib.common.recordings` says why a rebuild only reads them).

    python -m paper_lib.experiments.recordings example_states  # results/<profile>/recordings/example_states.npz
    python -m paper_lib.experiments.recordings quickstart      # results/<profile>/recordings/quickstart.npz

`make recollect` runs both (DVC stages `record_example_states` and `record_quickstart`); `make reproduce` never does.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from paper_lib.common.provenance import file_digest
from paper_lib.common.recordings import load_recording, save_recording
from paper_lib.pipeline.layout import QUICKSTART_RUN, Layout
from paper_lib.reporting.rendering import Frame

#: The member measures the quickstart follows along its episode.
QUICKSTART_MEASURES = ("value_std", "policy_std", "policy_js")


# ---- notebook 07: example states --------------------------------------------------------------------------------

def example_state_settings(mujoco_envs: list[str], atari_games: list[str], steps: int, seed: int) -> dict[str, Any]:
    return {"what": "example_states", "mujoco_envs": list(mujoco_envs), "atari_games": list(atari_games),
            "steps": steps, "seed": seed}


def play_example_states(mujoco_envs: list[str], atari_games: list[str], steps: int,
                        seed: int) -> tuple[dict[str, list[Frame]], str | None]:
    """({panel group: frames}, why MuJoCo frames are missing or None): MuJoCo ID/OOD states, Atari ID/OOD sources and
    the pixel perturbations, each after the same random actions."""
    from paper_lib.reporting.rendering import atari_examples, mujoco_examples, mujoco_rendering_problem, pixel_examples

    problem = mujoco_rendering_problem()
    groups = {} if problem else {f"mujoco_{env_id}": mujoco_examples(env_id, seed=seed, steps=steps)
                                 for env_id in mujoco_envs}
    groups |= {f"atari_{game}": atari_examples(game, seed=seed, steps=steps) for game in atari_games}
    groups |= {f"pixels_{game}": pixel_examples(game, seed=seed, steps=steps) for game in atari_games}
    return groups, problem


def save_example_states(path: str | Path, settings: dict[str, Any], groups: dict[str, list[Frame]],
                        problem: str | None) -> Path:
    titles = {group: [title for title, _ in frames] for group, frames in groups.items()}
    arrays = {f"{group}__{i}": frame for group, frames in groups.items() for i, (_, frame) in enumerate(frames)}
    return save_recording(path, {**settings, "titles": titles, "mujoco_problem": problem}, **arrays)


def load_example_states(path: str | Path, settings: dict[str, Any]) -> tuple[dict[str, list[Frame]], str | None]:
    recorded, arrays = load_recording(path, settings)
    groups = {group: [(title, arrays[f"{group}__{i}"]) for i, title in enumerate(titles)]
              for group, titles in recorded["titles"].items()}
    return groups, recorded["mujoco_problem"]


# ---- notebook 00: the quickstart's episode ----------------------------------------------------------------------

#: The member-free detectors the quickstart sets beside the members, in the order its figure draws them.
QUICKSTART_DETECTORS = ("knn_obs", "mahalanobis_obs", "knn_features", "mahalanobis_features")
#: Bump when what `score_gravity_episode` computes changes: a recording made before reads as one to make again.
QUICKSTART_SCORES_VERSION = 1


@dataclass
class QuickstartScores:
    """Every score the quickstart's figure ranks, computed once where the episode is played or recorded: torch and
    BLAS round the last bits differently on other CPUs, and a rebuild must draw the same figure on every machine."""

    n_fit: int  # ID states the detectors are fit on
    calibration: dict[str, np.ndarray]  # per score (members, then detectors): the calibration ID states' scores, sorted
    episode: dict[str, np.ndarray]  # per score, in the same order: its value at each step of the episode


@dataclass
class GravityEpisode:
    """One episode of a member policy whose gravity changes at `change_at`, and the ID states that calibrate it."""

    id_obs: np.ndarray  # the policy's observations of the ID states (normalized where the run normalizes)
    id_episodes: int  # how many episodes they came from
    observations: np.ndarray  # the policy's observation at each step of the episode
    member_scores: pd.DataFrame  # step and each QUICKSTART_MEASURES as the agent acted
    shots: list[tuple[int, np.ndarray]]  # (step, rendered frame)
    rendering_problem: str | None  # why there are no frames, or None
    scores: QuickstartScores  # every member measure and detector, on the calibration states and along the episode


def quickstart_settings(folder: str | Path, episode_steps: int, change_at: int, gravity: list[float],
                        n_id_states: int, seed: int, frames: int) -> dict[str, Any]:
    return {"what": "quickstart", "checkpoint_sha256": file_digest(Path(folder) / "model.zip"),
            "episode_steps": episode_steps, "change_at": change_at, "gravity": list(gravity),
            "n_id_states": n_id_states, "seed": seed, "frames": frames, "scores_version": QUICKSTART_SCORES_VERSION}


def score_gravity_episode(policy: Any, id_obs: np.ndarray, observations: np.ndarray, member_scores: pd.DataFrame,
                          seed: int) -> QuickstartScores:
    """Fit the member-free detectors on half of the ID states (on observations and on the policy's features) and score
    the other half, which calibrates every score's ID percentile, and the episode's observations. The members' episode
    scores are the ones the agent had as it acted (`member_scores`)."""
    import torch

    from paper_lib.measures.detectors import KNNDetector, MahalanobisDetector, split_fit_eval
    from paper_lib.measures.estimates import policy_features, uncertainty

    torch.manual_seed(seed)  # MC Dropout / DropConnect members draw their masks from torch
    fit_idx, calib_idx = split_fit_eval(len(id_obs), np.random.default_rng(seed))
    features = partial(policy_features, policy)  # the policy's last hidden layer
    raw = np.asarray
    detectors = {"knn_obs": (KNNDetector(), raw), "mahalanobis_obs": (MahalanobisDetector(), raw),
                 "knn_features": (KNNDetector(), features), "mahalanobis_features": (MahalanobisDetector(), features)}
    calib_obs = id_obs[calib_idx]
    calibration = dict(uncertainty(policy, calib_obs, list(QUICKSTART_MEASURES)))
    episode = {name: member_scores[name].to_numpy() for name in QUICKSTART_MEASURES}
    for name in QUICKSTART_DETECTORS:
        detector, inputs = detectors[name]
        detector.fit(inputs(id_obs[fit_idx]))
        calibration[name], episode[name] = detector.score(inputs(calib_obs)), detector.score(inputs(observations))
    return QuickstartScores(len(fit_idx), {name: np.sort(np.asarray(s)) for name, s in calibration.items()},
                            {name: np.asarray(s) for name, s in episode.items()})


def id_percentile(calibration: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """Share of the (sorted) calibration ID scores at most each of `scores`."""
    return np.searchsorted(calibration, scores, side="right") / len(calibration)


def play_gravity_change(folder: str | Path, episode_steps: int, change_at: int, gravity: list[float],
                        n_id_states: int, seed: int, frames: int) -> GravityEpisode:
    """Collect ID states, then play one episode in which gravity becomes `gravity` at step `change_at`."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    from paper_lib.agents.envs import make_single_env
    from paper_lib.measures.estimates import act_with_uncertainty
    from paper_lib.ood.collect import ActionMode, collect_id_states
    from paper_lib.ood.mujoco import PerturbationConfig
    from paper_lib.reporting.rendering import RENDER_KWARGS, mujoco_rendering_problem

    folder = Path(folder)
    torch.manual_seed(seed)  # MC Dropout / DropConnect members draw their masks from torch, actions are sampled
    env_id = json.loads((folder / "config.json").read_text())["env_id"]
    model = PPO.load(folder / "model.zip", device="cpu")
    policy = model.policy
    vecnormalize = None  # runs trained on normalized observations act on what their normalizer makes of raw ones
    if (folder / "vecnormalize.pkl").is_file():
        vecnormalize = VecNormalize.load(str(folder / "vecnormalize.pkl"), DummyVecEnv([lambda: make_single_env(env_id)]))
        vecnormalize.training, vecnormalize.norm_reward = False, False
    to_policy = vecnormalize.normalize_obs if vecnormalize is not None else (lambda obs: obs)

    id_data = collect_id_states(model, env_id, n_id_states, seed=seed + 1, vecnormalize=vecnormalize,
                                action_mode=ActionMode(deterministic=False, inference=policy.inference[0]))
    id_obs = id_data.policy_obs if id_data.policy_obs is not None else id_data.states

    problem = mujoco_rendering_problem() if frames > 0 else "no frames asked for (frames = 0)"
    render = {} if problem else RENDER_KWARGS
    shot_steps = set(np.linspace(0, episode_steps - 1, frames).round().astype(int).tolist()) if frames > 0 else set()
    shot_steps |= {change_at - 1, change_at + (episode_steps - change_at) // 4} if frames > 1 else set()
    perturbation = PerturbationConfig(env_id, gravity=tuple(gravity))
    env = make_single_env(env_id, **render)
    obs, _ = env.reset(seed=seed)
    steps, observations, shots = [], [], []
    for t in range(episode_steps):
        if t == change_at:  # the live MuJoCo model: the new gravity acts from the next physics step on
            env.unwrapped.model.opt.gravity[:] = perturbation.gravity
        policy_obs = to_policy(obs[None])[0]
        action, scores = act_with_uncertainty(policy, policy_obs, deterministic=False)
        observations.append(policy_obs)
        steps.append({"step": t, **{name: float(np.ravel(scores[name])[0]) for name in QUICKSTART_MEASURES}})
        if render and t in shot_steps:
            shots.append((t, env.render()))
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            break
    env.close()
    observations, member_scores = np.asarray(observations), pd.DataFrame(steps)
    return GravityEpisode(id_obs, len(np.unique(id_data.episode)), observations, member_scores, shots, problem,
                          score_gravity_episode(policy, id_obs, observations, member_scores, seed))


def save_gravity_episode(path: str | Path, settings: dict[str, Any], episode: GravityEpisode) -> Path:
    shots = {f"shot_{step}": frame for step, frame in episode.shots}
    scores = episode.member_scores
    ranked = {f"{part}__{name}": values for part in ("calibration", "episode")
              for name, values in getattr(episode.scores, part).items()}
    return save_recording(path, {**settings, "id_episodes": episode.id_episodes, "shot_steps": [s for s, _ in episode.shots],
                                 "rendering_problem": episode.rendering_problem, "n_fit": episode.scores.n_fit,
                                 "score_names": list(episode.scores.episode)},
                          id_obs=episode.id_obs, observations=episode.observations, steps=scores["step"].to_numpy(),
                          **{f"measure_{name}": scores[name].to_numpy() for name in QUICKSTART_MEASURES}, **shots,
                          **ranked)


def load_gravity_episode(path: str | Path, settings: dict[str, Any]) -> GravityEpisode:
    recorded, arrays = load_recording(path, settings)
    scores = pd.DataFrame({"step": arrays["steps"], **{name: arrays[f"measure_{name}"] for name in QUICKSTART_MEASURES}})
    names = recorded["score_names"]
    ranked = QuickstartScores(recorded["n_fit"], {name: arrays[f"calibration__{name}"] for name in names},
                              {name: arrays[f"episode__{name}"] for name in names})
    return GravityEpisode(arrays["id_obs"], recorded["id_episodes"], arrays["observations"], scores,
                          [(step, arrays[f"shot_{step}"]) for step in recorded["shot_steps"]],
                          recorded["rendering_problem"], ranked)


# ---- the command `make recollect` runs ---------------------------------------------------------------------------

#: The quickstart's episode's settings, as notebook 00's parameters cell has them (its agent: layout.QUICKSTART_RUN).
QUICKSTART_GRAVITY = [0.0, 0.0, -1.0]
QUICKSTART_SEED, QUICKSTART_FRAMES = 0, 6
#: Notebook 07's random actions before each picture, and their seed.
EXAMPLE_STEPS, EXAMPLE_SEED = 80, 0


def example_state_envs(profile: str) -> tuple[list[str], list[str]]:
    """(MuJoCo envs, Atari games) notebook 07 shows: all of the paper's, one of each in the `tiny` test profile."""
    from paper_lib.agents.envs import MUJOCO_ENVS
    from paper_lib.ood.atari import ATARI_GAMES

    tiny = profile == "tiny"
    return list(MUJOCO_ENVS[:1] if tiny else MUJOCO_ENVS), ["MsPacman"] if tiny else list(ATARI_GAMES)


def recording_path(results: Path, what: str) -> Path:
    """Where recording `what` of the results tree `results` lives (paper_lib.pipeline.layout)."""
    return Layout(Path(results)).recording(what)


def record(what: str, params: str | Path = "params.yaml") -> Path:
    """Record notebook 07's frames or notebook 00's episode for the active profile of `params`."""
    from paper_lib.pipeline.config import load_run_config

    cfg = load_run_config(params)
    out = recording_path(cfg.results, what)
    if what == "example_states":
        mujoco_envs, atari_games = example_state_envs(cfg.profile)
        settings = example_state_settings(mujoco_envs, atari_games, EXAMPLE_STEPS, EXAMPLE_SEED)
        return save_example_states(out, settings, *play_example_states(mujoco_envs, atari_games, EXAMPLE_STEPS,
                                                                       EXAMPLE_SEED))
    env_id, method, seed = QUICKSTART_RUN
    folder = cfg.checkpoint_dir(env_id, method, seed)
    if not (folder / "model.zip").is_file():
        raise FileNotFoundError(f"{folder} has no model.zip: the quickstart's agent is not trained in profile "
                                f"{cfg.profile!r}")
    steps = cfg.max_episode_steps
    args = (folder, steps, steps // 2, QUICKSTART_GRAVITY, cfg.n_id_states, QUICKSTART_SEED, QUICKSTART_FRAMES)
    return save_gravity_episode(out, quickstart_settings(*args), play_gravity_change(*args))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Record what notebooks 00 and 07 draw from simulation.")
    parser.add_argument("what", choices=("example_states", "quickstart"))
    parser.add_argument("--params", default="params.yaml", help="params.yaml whose active profile is recorded")
    args = parser.parse_args(argv)
    try:
        print(f"recorded {record(args.what, args.params)}")
    except (ValueError, FileNotFoundError) as err:
        parser.exit(2, f"error: {err}\n")


if __name__ == "__main__":
    import torch

    torch.set_num_threads(1)
    main()
