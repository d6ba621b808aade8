"""OOD Atari game states: each source really changes the emulated game, wrapped like the agent's env."""

from __future__ import annotations

import json

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from paper_lib.ood.atari import (
    ATARI_GAMES,
    DEFAULT_SOURCE,
    OOD_SOURCE_NOTES,
    AtariOODConfig,
    describe_source,
    indicator_name,
    make_atari_env_single,
    make_ood_atari_env,
    ood_sources,
    read_indicator,
    sample_atari_config,
    source_values,
)

N_STEPS = 50  # Seaquest's first enemies of a level appear after ~30 agent steps


def rollout(make_env, n_steps: int = N_STEPS, action_seed: int = 0) -> np.ndarray:
    """Stacked states (n_steps + 1, 84, 84, 4) under a fixed random action sequence."""
    venv = VecFrameStack(DummyVecEnv([make_env]), n_stack=4)
    rng = np.random.default_rng(action_seed)
    states = [venv.reset()[0]]
    for _ in range(n_steps):
        states.append(venv.step(rng.integers(venv.action_space.n, size=1))[0][0])
    venv.close()
    return np.stack(states)


@pytest.fixture(scope="module", params=ATARI_GAMES)
def id_rollout(request) -> tuple[str, np.ndarray]:
    game = request.param
    return game, rollout(lambda: make_atari_env_single(game, seed=1))


def test_id_env_is_seeded(id_rollout):
    game, states = id_rollout
    assert states.shape == (N_STEPS + 1, 84, 84, 4) and states.dtype == np.uint8
    # Same seed, same actions -> same states: any OOD difference below comes from the edit.
    np.testing.assert_array_equal(rollout(lambda: make_atari_env_single(game, seed=1)), states)


def test_default_source_changes_the_states(id_rollout):
    game, id_states = id_rollout
    source = DEFAULT_SOURCE[game]
    config = AtariOODConfig(game, source, source_values(game, source)[-1], seed=1)
    ood_states = rollout(lambda: make_ood_atari_env(config))
    assert ood_states.shape == id_states.shape and ood_states.dtype == np.uint8
    differs = (ood_states != id_states).any(axis=(1, 2, 3))
    # Seaquest's enemies (Berzerk's robots) are off screen for a while after a reset
    # (a death): those states match the ID ones, the others must not.
    assert differs.mean() > 0.4 and differs[-1], f"{config}: states differ at steps {np.flatnonzero(differs)}"


@pytest.mark.parametrize("game", ATARI_GAMES)
def test_every_source_changes_the_states(game):
    id_states = rollout(lambda: make_atari_env_single(game, seed=1), n_steps=40)
    for source in ood_sources(game):
        config = AtariOODConfig(game, source, source_values(game, source)[-1], seed=1)
        ood_states = rollout(lambda: make_ood_atari_env(config), n_steps=40)
        assert (ood_states != id_states).any(), f"{config} left the game unchanged"


@pytest.mark.parametrize(("game", "address"), [("Seaquest", 60), ("Seaquest", 61), ("MsPacman", 0), ("Berzerk", 92)])
def test_ram_edit_in_force_after_every_reset(game, address):
    config = AtariOODConfig(game, DEFAULT_SOURCE[game], source_values(game, DEFAULT_SOURCE[game])[0], seed=3)
    env = make_ood_atari_env(config, terminal_on_life_loss=False)
    for _ in range(2):  # the second reset is a real emulator reset too
        env.reset()
        assert env.unwrapped.ale.getRAM()[address] == config.value
    env.close()


def test_sources_and_notes_cover_every_game():
    assert ATARI_GAMES == ("Seaquest", "MsPacman", "Berzerk", "SpaceInvaders")
    for game in ATARI_GAMES:
        sources = ood_sources(game)
        assert sources[0] == DEFAULT_SOURCE[game] and len(set(sources)) == len(sources)
        assert f"`{DEFAULT_SOURCE[game]}`" in OOD_SOURCE_NOTES[game]
        assert all(describe_source(game, s).startswith(f"{game} {s} (") for s in sources)


def test_sample_is_seeded_valid_and_json_serializable():
    for game in ATARI_GAMES:
        a = sample_atari_config(game, np.random.default_rng(7))
        assert a == sample_atari_config(game, np.random.default_rng(7))
        assert a.source == DEFAULT_SOURCE[game] and a.value in source_values(game, a.source)
        assert AtariOODConfig.from_json(a.to_json()) == a
        assert json.loads(a.to_json()) == {"game": game, "source": a.source, "value": a.value, "seed": a.seed}
    values = {sample_atari_config("MsPacman", np.random.default_rng(s)).value for s in range(30)}
    assert values == set(source_values("MsPacman", "maze"))
    other = sample_atari_config("SpaceInvaders", np.random.default_rng(0), source="difficulty")
    assert (other.source, other.value) == ("difficulty", 1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"game": "Pong", "source": "mode", "value": 1}, "Unknown Atari game 'Pong'"),
        ({"game": "SeaquestNoFrameskip-v4", "source": "level", "value": 1}, "Unknown Atari game"),
        ({"game": "MsPacman", "source": "level", "value": 1}, "Unknown OOD source 'level' for MsPacman"),
        ({"game": "MsPacman", "source": "maze", "value": 0}, "value=0 is not valid for MsPacman/maze"),
        ({"game": "Berzerk", "source": "mode", "value": 1}, "value=1 is not valid"),
        ({"game": "SpaceInvaders", "source": "mode", "value": 2.0}, "value=2.0 is not valid"),
        ({"game": "Seaquest", "source": "level", "value": 3, "seed": -1}, "seed=-1"),
    ],
)
def test_invalid_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AtariOODConfig(**kwargs)


def test_invalid_inputs_raise_where_they_enter():
    with pytest.raises(ValueError, match="unknown \\['level'\\]"):
        AtariOODConfig.from_dict({"game": "MsPacman", "source": "maze", "value": 1, "level": 3})
    with pytest.raises(ValueError, match="numpy Generator"):
        sample_atari_config("MsPacman", 0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="Unknown Atari game"):
        sample_atari_config("Breakout", np.random.default_rng(0))
    with pytest.raises(ValueError, match="Unknown AtariWrapper arguments \\['frameskip'\\]"):
        make_atari_env_single("MsPacman", seed=0, frameskip=4)
    with pytest.raises(ValueError, match="config must be an AtariOODConfig"):
        make_ood_atari_env({"game": "MsPacman", "source": "maze", "value": 1})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="seed=-3"):
        make_atari_env_single("Berzerk", seed=-3)


@pytest.mark.parametrize("game", ATARI_GAMES)
def test_the_indicator_reads_what_the_default_source_sets(game):
    """The coverage check reads this on the ID rollouts: the default game reads no OOD value, an edited one its value."""
    source = DEFAULT_SOURCE[game]
    id_env = make_atari_env_single(game, seed=0)
    id_env.reset()
    assert read_indicator(id_env, game, source) not in source_values(game, source)
    for value in (source_values(game, source)[0], source_values(game, source)[-1]):
        env = make_ood_atari_env(AtariOODConfig(game, source, value, seed=0))
        env.reset()
        assert read_indicator(env, game, source) == value
    expected = {"Seaquest": "RAM 60", "MsPacman": "RAM 0", "Berzerk": "RAM 92", "SpaceInvaders": "ALE mode"}
    assert indicator_name(game, source) == expected[game]
