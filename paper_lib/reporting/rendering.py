"""Pictures of ID and OOD states: MuJoCo frames per physics perturbation, Atari screens per OOD source.

MuJoCo renders offscreen through EGL (``MUJOCO_GL=egl``, set here unless the caller chose
another backend): it needs no display, only the EGL and OpenGL libraries (``make render-deps``
installs them on Debian/Ubuntu). Where they are missing, `mujoco_rendering_problem` says so and
callers skip the MuJoCo frames instead of failing. Atari screens come from the emulator and
need nothing. Random actions with fixed seeds: the pictures show states, not an agent's skill,
and are the same on every run.
"""

from __future__ import annotations

import os
import subprocess
import sys
from functools import cache

import numpy as np

os.environ.setdefault("MUJOCO_GL", "egl")  # before any MuJoCo renderer exists; osmesa and glfw fail headless

Frame = tuple[str, np.ndarray]  # (title, image)
#: gym.make kwargs of a rendering MuJoCo env: small frames from each model's own side camera that follows the robot.
RENDER_KWARGS = {"render_mode": "rgb_array", "width": 240, "height": 180, "camera_name": "track"}

_PROBE = ("import mujoco; m = mujoco.MjModel.from_xml_string('<mujoco/>'); r = mujoco.Renderer(m, 16, 16); "
          "r.update_scene(mujoco.MjData(m)); assert r.render().shape == (16, 16, 3); r.close()")


@cache
def mujoco_rendering_problem() -> str | None:
    """None if MuJoCo can render offscreen here, else one line saying why and how to fix it.

    Probed in a child process: a missing GL library can crash the interpreter, not only raise.
    """
    try:
        done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120,
                              env={**os.environ, "MUJOCO_GL": os.environ["MUJOCO_GL"]}, check=False)
    except subprocess.TimeoutExpired:
        return "MuJoCo offscreen rendering did not answer within 120 s"
    if done.returncode == 0:
        return None
    last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
    return (f"MuJoCo offscreen rendering (MUJOCO_GL={os.environ['MUJOCO_GL']}) is unavailable here ({last}); "
            "install the EGL libraries with `make render-deps` (Debian/Ubuntu, as root) to get the frames")


def _actions(space, n: int, seed: int) -> list:
    space.seed(seed)
    return [space.sample() for _ in range(n)]


def _mujoco_rollout_frame(env, actions: list, seed: int) -> np.ndarray:
    """Reset with `seed`, play `actions` (stopping early if the episode ends), render the last state."""
    try:
        env.reset(seed=seed)
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        return env.render()
    finally:
        env.close()


def mujoco_examples(env_id: str, seed: int = 0, steps: int = 80) -> list[Frame]:
    """The default env and one perturbation of each kind (paper appendix G), after the same `steps` random actions.

    Each perturbed env has one kind only, drawn from the paper's ranges with `seed`; its title
    says what was drawn. The four kinds act differently: geometry shows at once, gravity,
    wind and friction show through the motion they cause.
    """
    from paper_lib.agents.envs import make_single_env
    from paper_lib.ood.mujoco import (
        make_perturbed_env,
        perturbation_kinds,
        sample_config,
    )

    render = RENDER_KWARGS
    env = make_single_env(env_id, **render)
    actions = _actions(env.action_space, steps, seed)
    frames = [(f"ID: default physics, step {steps}", _mujoco_rollout_frame(env, actions, seed))]
    for i, kind in enumerate(perturbation_kinds(env_id)):
        config = sample_config(env_id, np.random.default_rng([seed, i]), kinds=[kind])
        what = config.describe().split(": ", 1)[1]
        frames.append((f"OOD {kind}: {what}", _mujoco_rollout_frame(make_perturbed_env(config, **render), actions, seed)))
    return frames


def _atari_screen(env, actions: list) -> np.ndarray:
    """Play `actions` from the env's (seeded) reset and return the emulator's RGB screen."""
    try:
        env.reset()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
        return env.unwrapped.ale.getScreenRGB()
    finally:
        env.close()


def _quiet_ale() -> None:
    """ALE prints its version banner to the process's stderr at the first emulator; an executed notebook keeps it."""
    import ale_py

    ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Error)


def atari_examples(game: str, seed: int = 0, steps: int = 60) -> list[Frame]:
    """The default game and each OOD source of `paper_lib.ood.atari` (its middle value), after the same random actions."""
    from paper_lib.ood.atari import (
        AtariOODConfig,
        make_atari_env_single,
        make_ood_atari_env,
        ood_sources,
        source_values,
    )

    _quiet_ale()
    env = make_atari_env_single(game, seed=seed)
    actions = _actions(env.action_space, steps, seed)
    frames = [(f"ID: {game}, step {steps}", _atari_screen(env, actions))]
    for source in ood_sources(game):
        values = source_values(game, source)
        value = values[len(values) // 2]
        env = make_ood_atari_env(AtariOODConfig(game, source, value, seed=seed))
        frames.append((f"OOD {source} = {value}", _atari_screen(env, actions)))
    return frames


def agent_view(game: str, seed: int = 0, steps: int = 60) -> np.ndarray:
    """The agent's observation after `steps` random actions: 84x84 grey frames, 4 stacked, shape (1, 84, 84, 4)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

    from paper_lib.agents.envs import N_STACK
    from paper_lib.ood.atari import make_atari_env_single

    _quiet_ale()
    venv = VecFrameStack(DummyVecEnv([lambda: make_atari_env_single(game, seed=seed)]), N_STACK)
    try:
        obs = venv.reset()
        for action in _actions(venv.action_space, steps, seed):
            obs, _, _, _ = venv.step(np.array([action]))
        return obs
    finally:
        venv.close()


def pixel_examples(game: str, seed: int = 0, steps: int = 60) -> list[Frame]:
    """An ID agent observation and each pixel perturbation of it (paper appendix H); the newest stacked frame shown."""
    from paper_lib.ood.pixels import PIXEL_PERTURBATIONS, perturb_pixels

    obs = agent_view(game, seed, steps)
    frames = [(f"ID: {game} as the agent sees it", obs[0, :, :, -1])]
    for kind in PIXEL_PERTURBATIONS:
        frames.append((kind, perturb_pixels(obs, kind, np.random.default_rng(seed))[0, :, :, -1]))
    return frames
