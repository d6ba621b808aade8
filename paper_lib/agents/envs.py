"""Environment ids and vectorized env factories (MuJoCo v5, Atari with SB3's wrappers)."""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from stable_baselines3.common.env_util import make_atari_env, make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecFrameStack, VecNormalize

MUJOCO_ENVS = ("HalfCheetah-v5", "Ant-v5", "Walker2d-v5", "Swimmer-v5")
ATARI_ENVS = ("SeaquestNoFrameskip-v4", "MsPacmanNoFrameskip-v4", "BerzerkNoFrameskip-v4", "SpaceInvadersNoFrameskip-v4")
N_STACK = 4


#: Model files written by paper_lib stay on disk: gym.make(env.spec) and vec-envs re-read the path.
MODEL_CACHE = Path(tempfile.gettempdir()) / "paper_lib_mujoco_models"
#: Gymnasium's model file of each MuJoCo env.
MUJOCO_XML = {"HalfCheetah-v5": "half_cheetah.xml", "Ant-v5": "ant.xml", "Walker2d-v5": "walker2d_v5.xml",
              "Swimmer-v5": "swimmer.xml"}


def is_atari(env_id: str) -> bool:
    return env_id.endswith("NoFrameskip-v4")


def register_atari() -> None:
    """ale-py ships the ROMs but gymnasium only knows its ids after registration."""
    import ale_py

    gym.register_envs(ale_py)


def check_atari_rom(env_id: str) -> None:
    """A missing ROM file is one error with its fix: ale-py would raise a bare FileNotFoundError from deep inside."""
    import ale_py.roms

    game = gym.spec(env_id).kwargs.get("game")
    roms_dir = Path(os.environ.get("ALE_ROMS_DIR") or Path(ale_py.roms.__file__).parent)
    if game and not (roms_dir / f"{game}.bin").is_file():
        where = "ALE_ROMS_DIR" if os.environ.get("ALE_ROMS_DIR") else "ale-py's ROM folder"
        raise FileNotFoundError(f"the Atari ROM of {env_id} ({game}.bin) is not in {roms_dir} ({where}): ale-py ships "
                                "the ROMs, so reinstall it from the lock file (`make setup`, or `.venv/bin/pip install "
                                "--force-reinstall ale-py`)" + (", or unset ALE_ROMS_DIR" if where == "ALE_ROMS_DIR"
                                                                else ""))


def make_registered_atari(env_id: str, **gym_kwargs: Any) -> gym.Env:
    """gym.make of an ALE id in any process: an env subprocess starts without the registration."""
    register_atari()
    check_atari_rom(env_id)
    return gym.make(env_id, **gym_kwargs)


def gymnasium_asset(xml: str) -> str:
    """Absolute path of one of Gymnasium's MuJoCo model files."""
    return os.path.join(os.path.dirname(gym.__file__), "envs", "mujoco", "assets", xml)


def replace_total_mass_by_density(spec: mujoco.MjSpec) -> None:
    """Replace the deprecated ``settotalmass`` by the geom densities that give the same masses.

    half_cheetah.xml rescales all masses to 14 kg, an attribute MuJoCo 4 deprecates (and warns
    about at every env creation). Scaling the densities instead gives the same compiled masses
    and inertias (to the 7 significant digits `to_xml` keeps), and lets a perturbed, longer
    part gain mass with its volume instead of shrinking every other part to keep 14 kg. It must
    run before any geometry edit.
    """
    total = spec.compiler.settotalmass
    if total <= 0:
        return
    spec.compiler.settotalmass = -1
    raw = spec.compile().body_subtreemass[0]
    for geom in spec.geoms:
        geom.density *= total / raw


def model_spec(env_id: str) -> mujoco.MjSpec:
    """The env's model as an editable MjSpec, free of deprecated attributes."""
    spec = mujoco.MjSpec.from_file(gymnasium_asset(MUJOCO_XML[env_id]))
    replace_total_mass_by_density(spec)
    return spec


def write_model_xml(spec: mujoco.MjSpec) -> str:
    """Write a model once under a content-hash name (atomically) and return its absolute path."""
    spec.compile()
    xml = spec.to_xml()
    MODEL_CACHE.mkdir(parents=True, exist_ok=True)
    path = MODEL_CACHE / f"{hashlib.sha256(xml.encode()).hexdigest()[:20]}.xml"
    if not path.exists():
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(xml)
        os.replace(tmp, path)
    return str(path.resolve())


@cache
def _default_model_file(env_id: str) -> str | None:
    spec = mujoco.MjSpec.from_file(gymnasium_asset(MUJOCO_XML[env_id]))
    if spec.compiler.settotalmass <= 0:
        return None  # Gymnasium's own file is fine
    return write_model_xml(model_spec(env_id))


def default_env_kwargs(env_id: str) -> dict[str, Any]:
    """gym.make kwargs every env of `env_id` gets: HalfCheetah loads its model without settotalmass."""
    if env_id not in MUJOCO_XML:
        return {}
    model_file = _default_model_file(env_id)
    if model_file is None or not Path(model_file).is_file():
        _default_model_file.cache_clear()
        model_file = _default_model_file(env_id)
    return {} if model_file is None else {"xml_file": model_file}


def make_single_env(env_id: str, **gym_kwargs: Any) -> gym.Env:
    """gym.make with paper_lib's model for MuJoCo envs (see `default_env_kwargs`)."""
    return gym.make(env_id, **{**default_env_kwargs(env_id), **gym_kwargs})


def wrapped_env_ids(venv: VecEnv) -> list[str]:
    """The Gymnasium ids a VecEnv runs (through any wrappers); [] where it cannot say."""
    try:
        return sorted({spec.id for spec in venv.get_attr("spec") if spec is not None})
    except (AttributeError, TypeError):  # a VecEnv that cannot say which env it runs
        return []


def check_given_env(venv: VecEnv, env_id: str, where: str = "make_agent") -> None:
    """A given env must run `env_id`: a model of one env trained in another's would save the first's config.json.

    Named by its ids where it can say them, else by its observation shape against `env_id`'s."""
    ids = wrapped_env_ids(venv)
    if ids and ids != [env_id]:
        raise ValueError(f"{where}: the given env runs {', '.join(ids)} but env_id is {env_id!r}; pass an env of "
                         f"{env_id} (make_env({env_id!r}, n_envs, seed)) or env_id={ids[0]!r}")
    if ids:
        return
    reference = make_env(env_id, 1, 0)
    shape = reference.observation_space.shape
    reference.close()
    if venv.observation_space.shape != shape:
        raise ValueError(f"{where}: the given env has observations of shape {venv.observation_space.shape} but "
                         f"{env_id}'s have shape {shape}; pass an env of {env_id} (make_env({env_id!r}, n_envs, seed))")


#: The attribute a saved VecNormalize records its env id under (pickled with it; SB3 keeps unknown attributes).
NORMALIZER_ENV_ID = "paper_lib_env_id"


def save_normalizer(normalizer: VecNormalize, path: Path, env_id: str) -> None:
    """VecNormalize.save with the env id recorded: a pkl holds only statistics, so one of another env of the same
    observation shape (HalfCheetah, Walker2d: 17) could not be told apart when loaded."""
    setattr(normalizer, NORMALIZER_ENV_ID, env_id)
    normalizer.save(str(path))


def normalizer_env_id(normalizer: VecNormalize) -> str | None:
    """The env id a saved normalizer recorded; None for one saved before the id was recorded. Read from the
    instance itself: VecEnvWrapper's attribute lookup would search an unpickled one's absent venv without end."""
    return vars(normalizer).get(NORMALIZER_ENV_ID)


def check_env_seed(seed: Any, where: str = "make_env") -> int | None:
    """`seed` as a plain int (gymnasium refuses numpy integers such as the np.int64 it hands out itself).

    Booleans pass for ints in Python and are refused; None leaves the envs unseeded, as in SB3.
    """
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
        raise ValueError(f"{where}: seed must be an integer >= 0, got {seed!r}; pass e.g. seed=0")
    if seed < 0:
        raise ValueError(f"{where}: seed must be an integer >= 0, got {seed!r}; numpy refuses negative seeds")
    return int(seed)


def make_env(env_id: str, n_envs: int, seed: int, normalize_obs: bool = False,
             env_kwargs: dict[str, Any] | None = None, normalize_reward: bool = False,
             gamma: float = 0.99, env_processes: bool = False) -> VecEnv:
    """The vectorized env an agent trains in: Atari gets AtariWrapper + 4 stacked frames.

    ``env_processes`` steps each env in its own process (SubprocVecEnv) instead of in turn in this
    one: the same transitions for the same seed, faster where cores are many and the networks run
    on a GPU (then stepping Atari envs, not the networks, bounds a run).

    ``normalize_reward`` scales training rewards by the running std of the discounted return
    (VecNormalize, with the algorithm's ``gamma`` as rl-baselines3-zoo passes it); evaluation
    always undoes it (`Checkpoint.env`), so reported rewards are the env's own.
    """
    seed = check_env_seed(seed)
    vec_env_cls = SubprocVecEnv if env_processes else DummyVecEnv
    if is_atari(env_id):
        register_atari()
        check_atari_rom(env_id)
        game: Any = functools.partial(make_registered_atari, env_id) if env_processes else env_id
        venv: VecEnv = VecFrameStack(make_atari_env(game, n_envs, seed=seed, vec_env_cls=vec_env_cls,
                                                    env_kwargs=env_kwargs), N_STACK)
    else:
        venv = make_vec_env(env_id, n_envs, seed=seed, vec_env_cls=vec_env_cls,
                            env_kwargs={**default_env_kwargs(env_id), **(env_kwargs or {})})
    if normalize_reward:
        venv = VecNormalize(venv, norm_obs=normalize_obs, norm_reward=True, gamma=gamma)
    elif normalize_obs:
        venv = VecNormalize(venv, norm_obs=True, norm_reward=False)
    return venv
