"""Valid Atari game states that a trained agent never sees: the OOD states of the benchmark.

The paper took them from Atari-HEAD human play at advanced levels (see ``atari_head.py``
for a loader of a local copy). That data set cannot be fetched here, so this module
makes the emulator itself start in such states: an ALE game mode or difficulty (a rule
variant) passed to ``gym.make``, or RAM bytes written after every emulator reset (the
game level, maze, lives...). Each edit was checked to act on the emulator (frames and
RAM differ from the default game under the same seeded actions; see ``OOD_SOURCE_NOTES``).

ID and OOD envs share one factory, so both are wrapped exactly like the agent's training
env (``make_atari_env``: gym.make -> Monitor -> AtariWrapper). Wrap the result in
``DummyVecEnv`` + ``VecFrameStack(n_stack=4)`` to get (84, 84, 4) uint8 states.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

import ale_py
import gymnasium as gym
import numpy as np
from stable_baselines3.common.atari_wrappers import AtariWrapper
from stable_baselines3.common.monitor import Monitor

ATARI_GAMES: tuple[str, ...] = ("Seaquest", "MsPacman", "Berzerk", "SpaceInvaders")
_WRAPPER_KWARGS = ("noop_max", "frame_skip", "screen_size", "terminal_on_life_loss", "clip_reward",
                   "action_repeat_probability")


@dataclass(frozen=True)
class _Source:
    """One way to put a game into unseen states; ``value`` picks its strength.

    ``ram``: addresses set to ``value`` after every real emulator reset.
    ``make_arg``: "mode" or "difficulty", passed to ``gym.make`` (an ALE rule variant).
    """

    values: tuple[int, ...]
    ram: tuple[int, ...] = ()
    make_arg: str | None = None
    what: str = ""


_SOURCES: dict[str, dict[str, _Source]] = {
    "Seaquest": {
        # The game itself sets RAM 60 (surface-patrol counter) and 61 to k after the k-th
        # surfacing with six rescued divers (checked with a scripted dive). RAM 61 alone already
        # goes 0 -> 1 at the first surfacing with any diver aboard (seen in untrained play), so
        # the indicator the coverage checks read is RAM 60, which only six-diver surfacings move.
        "level": _Source(tuple(range(1, 17)), ram=(60, 61),
                         what="later level: new enemy colours and formations, a patrol sub on the surface"),
        "extra_lives": _Source((4, 5, 6), ram=(59,),
                               what="reserve submarines shown at the top (one is earned per 10,000 points)"),
        "divers": _Source((4, 5, 6), ram=(62,), what="many rescued divers shown above the logo"),
        "difficulty": _Source((1,), make_arg="difficulty",
                              what="ALE difficulty 1: only the torpedo's RAM differs (a weak source)"),
    },
    "MsPacman": {
        "maze": _Source((1, 2, 3), ram=(0,), what="the maze layouts of later levels"),
        "mode": _Source((1, 2, 3), make_arg="mode", what="ALE game variant: another bonus fruit, and play diverges"),
    },
    "Berzerk": {
        # RAM 92 counts the rooms entered (+1 per room, also after a death); the robots'
        # colour follows (value // 2) % 8: yellow, orange, white, green, pink, blue, gold, purple.
        "level": _Source(tuple(range(10, 16)), ram=(92,),
                         what="rooms 10-15: blue, gold and purple robots"),
        "mode": _Source((2, 3, 4, 5, 6, 7, 8, 9, 16, 17, 18), make_arg="mode",
                        what="ALE game variant: Evil Otto, other room sequences"),
    },
    "SpaceInvaders": {
        # The 2600 variants are bit flags: 1 moving shields, 2 zigzag bombs, 4 fast
        # bombs, 8 invisible invaders.
        "mode": _Source(tuple(range(1, 16)), make_arg="mode",
                        what="ALE game variant: moving shields, zigzag/fast bombs, invisible invaders"),
        "difficulty": _Source((1,), make_arg="difficulty", what="ALE difficulty 1: a wider laser cannon"),
        # RAM 16 is the formation's descent. Wave 2 starts at 5 (measured by clearing wave 1
        # with a scripted policy), which a good agent reaches: use lower starts only.
        "low_invaders": _Source((6, 7, 8), ram=(16,),
                                what="a full formation that starts lower, as later waves do"),
    },
}

DEFAULT_SOURCE: dict[str, str] = {
    "Seaquest": "level",
    "MsPacman": "maze",
    "Berzerk": "level",
    "SpaceInvaders": "mode",
}

OOD_SOURCE_NOTES: dict[str, str] = {
    "Seaquest": (
        "Default `level` (values 1-16): RAM bytes 60 and 61 are set to k after every reset, the state the game "
        "itself enters after the k-th surfacing with six rescued divers (checked with a scripted dive). RAM 61 "
        "alone goes to 1 at the first surfacing with any diver aboard, which agents do; RAM 60 (the surface "
        "patrol) moves only with six divers, so it is the indicator the coverage checks read. "
        "Enemies change colour and formation, and at higher levels an enemy patrols the surface. Agents at "
        "the paper's scores (~4,000) never surface with six divers, so they only ever see level 0. The first "
        "enemies enter about 30 agent steps after a reset or a death; the states before look like level 0, "
        "so drop them (as the paper dropped the first 10 states of each MuJoCo episode). Also available: "
        "`extra_lives` and `divers` (HUD states of strong human play, the paper's Seaquest example) and "
        "`difficulty` 1 (only the torpedo's RAM differs: a weak source)."
    ),
    "MsPacman": (
        "Default `maze` (values 1-3): RAM byte 0 is set to k after every reset, which gives the maze layouts "
        "of later levels (15-17% of the screen's pixels differ from the first maze). Agents at the paper's "
        "scores (~2,400) do not clear the first levels, and the paper names this very example (the level "
        "'can be selected at initialization'). Also available: ALE `mode` 1-3 (another bonus fruit, and the "
        "play diverges from the default within a few steps; a small change of the picture)."
    ),
    "Berzerk": (
        "Default `level` (values 10-15): RAM byte 92 counts the rooms entered in a game (also after each "
        "death) and sets the robots' colour; 10-15 give blue, gold and purple robots, which an agent meets "
        "only after at least seven room exits in one game (the paper's agents score ~600, about 12 robots). "
        "Check this against the ID rollouts by logging `env.unwrapped.ale.getRAM()[92]`. Robots appear 3 "
        "agent steps after a reset and vanish during the death animation: those states match the ID ones. "
        "Also available: ALE `mode` (Evil Otto and other variants)."
    ),
    "SpaceInvaders": (
        "Default `mode` (values 1-15): the 2600 game variants (moving shields, zigzag or fast bombs, "
        "invisible invaders, and their combinations), valid game states with rules and pictures that an "
        "agent trained on variant 0 never saw. Also available: `difficulty` 1 (a wider cannon) and "
        "`low_invaders` (a full formation that starts lower, as later waves do)."
    ),
}


def _check_game(game: str) -> None:
    if not isinstance(game, str) or game not in ATARI_GAMES:
        raise ValueError(f"Unknown Atari game {game!r}: use one of {list(ATARI_GAMES)} (no 'NoFrameskip-v4').")


def env_id(game: str) -> str:
    """Gymnasium id of the game as the agents train on it."""
    _check_game(game)
    return f"{game}NoFrameskip-v4"


def game_of(atari_env_id: str) -> str:
    """The benchmark's game name of a gymnasium id, the inverse of ``env_id`` ("SeaquestNoFrameskip-v4" -> "Seaquest")."""
    game = atari_env_id.removesuffix("NoFrameskip-v4")
    if game not in ATARI_GAMES:
        raise ValueError(f"unknown Atari env {atari_env_id!r}: use one of {[env_id(g) for g in ATARI_GAMES]}.")
    return game


def ood_sources(game: str) -> list[str]:
    """Names of the OOD sources of ``game``; the default one first."""
    _check_game(game)
    default = DEFAULT_SOURCE[game]
    return [default] + [s for s in _SOURCES[game] if s != default]


def source_values(game: str, source: str) -> tuple[int, ...]:
    """Valid ``value`` settings of a source."""
    _check_game(game)
    if not isinstance(source, str) or source not in _SOURCES[game]:
        raise ValueError(f"Unknown OOD source {source!r} for {game}: use one of {ood_sources(game)}.")
    return _SOURCES[game][source].values


def describe_source(game: str, source: str) -> str:
    """One line on what a source changes, e.g. for table captions."""
    source_values(game, source)  # validates
    spec = _SOURCES[game][source]
    how = f"RAM {list(spec.ram)} := value" if spec.ram else f"ALE {spec.make_arg} = value"
    return f"{game} {source} ({how}): {spec.what}"


def indicator_name(game: str, source: str) -> str:
    """What ``read_indicator`` reads for a source: "RAM 92", "ALE mode", ...

    A RAM source is read at its first address (Seaquest's level at RAM 60, the surface-patrol
    counter, which only six-diver surfacings move; not RAM 61, which ordinary surfacing moves too).
    """
    source_values(game, source)  # validates
    spec = _SOURCES[game][source]
    return f"RAM {spec.ram[0]}" if spec.ram else f"ALE {spec.make_arg}"


def read_indicator(env: gym.Env, game: str, source: str) -> int:
    """The current value of ``source``'s indicator in ``env`` (one made by this module).

    This is the quantity the source sets to one of its OOD values: the RAM byte (the game's
    own counter, so ID play may reach it: that is what the coverage check looks for), or the
    mode or difficulty the env was made with (ALE's default, the lowest available one for
    these four games, when none was given: ID play can never change it).
    """
    source_values(game, source)  # validates
    spec = _SOURCES[game][source]
    ale = env.unwrapped.ale
    if spec.ram:
        return int(ale.getRAM()[spec.ram[0]])
    available = ale.getAvailableModes() if spec.make_arg == "mode" else ale.getAvailableDifficulties()
    return int(env.unwrapped.spec.kwargs.get(spec.make_arg, min(available)))


@dataclass(frozen=True)
class AtariOODConfig:
    """One OOD environment: ``game`` started in ``source`` at strength ``value``; ``seed`` seeds the env."""

    game: str
    source: str
    value: int
    seed: int = 0

    def __post_init__(self) -> None:
        values = source_values(self.game, self.source)
        if isinstance(self.value, bool) or not isinstance(self.value, (int, np.integer)) or self.value not in values:
            raise ValueError(f"value={self.value!r} is not valid for {self.game}/{self.source}: "
                             f"use one of {list(values)}.")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed={self.seed!r}: need a non-negative int.")
        # numpy ints would break json.dumps: store plain ints.
        object.__setattr__(self, "value", int(self.value))
        object.__setattr__(self, "seed", int(self.seed))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AtariOODConfig:
        fields = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(data, dict):
            raise ValueError(f"AtariOODConfig: expected an object with keys {sorted(fields)}, got {data!r}.")
        unknown = set(data) - fields
        missing = {"game", "source", "value"} - set(data)
        if unknown or missing:
            raise ValueError(f"AtariOODConfig keys: unknown {sorted(unknown)}, missing {sorted(missing)}; "
                             f"expected {sorted(fields)}.")
        return cls(**data)

    @classmethod
    def from_json(cls, text: str) -> AtariOODConfig:
        try:
            data = json.loads(text)
        except (json.JSONDecodeError, TypeError) as err:
            raise ValueError(f"AtariOODConfig JSON is not valid JSON ({err}): {str(text)[:200]!r}") from None
        return cls.from_dict(data)


def sample_atari_config(game: str, rng: np.random.Generator, source: str | None = None) -> AtariOODConfig:
    """Draw a value (and an env seed) for ``source``, the game's default source if None."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    _check_game(game)
    source = DEFAULT_SOURCE[game] if source is None else source
    values = source_values(game, source)
    value = int(values[int(rng.integers(len(values)))])
    return AtariOODConfig(game, source, value, seed=int(rng.integers(2**31 - 1)))


class ResetEdit(gym.Wrapper):
    """Writes RAM bytes after every real emulator reset and seeds the first reset.

    It sits right above the ALE env, below Monitor and AtariWrapper, so the no-op
    reset, frame skipping and life-loss logic of the agent's wrappers all run on the
    edited game. A lost life does not reset the emulator, so the edit stays in force
    for the whole game. With no RAM writes it is the ID env (seeding only).
    """

    def __init__(self, env: gym.Env, ram: dict[int, int], seed: int | None) -> None:
        super().__init__(env)
        self.ram = dict(ram)
        self._first_seed = seed
        if seed is not None:
            self.action_space.seed(seed)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is None:
            seed, self._first_seed = self._first_seed, None
        else:
            self._first_seed = None
        obs, info = self.env.reset(seed=seed, options=options)
        # The screen shows the edit from the next emulated frame on: AtariWrapper's no-op
        # reset runs at least one. No extra frame here, so that ID and OOD envs with the
        # same seed run the same frames and differ only by the edit.
        ale = self.env.unwrapped.ale
        for address, value in self.ram.items():
            ale.setRAM(address, value)
        return obs, info


def _make(game: str, seed: int, ram: dict[int, int], make_kwargs: dict[str, int],
          wrapper_kwargs: dict[str, Any]) -> gym.Env:
    unknown = set(wrapper_kwargs) - set(_WRAPPER_KWARGS)
    if unknown:
        raise ValueError(f"Unknown AtariWrapper arguments {sorted(unknown)}: use {list(_WRAPPER_KWARGS)}.")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed={seed!r}: need a non-negative int.")
    gym.register_envs(ale_py)
    env = gym.make(env_id(game), **make_kwargs)
    env = ResetEdit(env, ram, int(seed))
    env = Monitor(env)  # as make_atari_env does: episode returns in info["episode"]
    return AtariWrapper(env, **wrapper_kwargs)


def make_atari_env_single(game: str, seed: int = 0, **wrapper_kwargs: Any) -> gym.Env:
    """The default (ID) game, wrapped exactly like the OOD envs and the agent's env."""
    return _make(game, seed, {}, {}, wrapper_kwargs)


def make_ood_atari_env(config: AtariOODConfig, **wrapper_kwargs: Any) -> gym.Env:
    """A gymnasium env that starts every game in the state ``config`` describes.

    ``wrapper_kwargs`` go to SB3's AtariWrapper (defaults: the agent's training setup).
    RAM edits show on screen from the first emulated frame after the reset; with
    ``noop_max=0`` the observation that ``reset`` returns still predates them.
    """
    if not isinstance(config, AtariOODConfig):
        raise ValueError(f"config must be an AtariOODConfig, got {type(config).__name__}.")
    spec = _SOURCES[config.game][config.source]
    ram = {address: config.value for address in spec.ram}
    make_kwargs = {spec.make_arg: config.value} if spec.make_arg else {}
    return _make(config.game, config.seed, ram, make_kwargs, wrapper_kwargs)
