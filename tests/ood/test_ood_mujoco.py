"""MuJoCo OOD perturbations: each one must change the physics, and configs must be reproducible."""

import json
import math
import warnings
from functools import cache

import numpy as np
import pytest

from paper_lib.ood.mujoco import (
    SUPPORTED_ENVS,
    PerturbationConfig,
    PerturbationRanges,
    UnstablePerturbationWarning,
    geometry_parts,
    is_unstable,
    make_perturbed_env,
    perturbation_kinds,
    sample_config,
    sample_stable_config,
)

N_STEPS = 150
# A perturbation that does nothing reproduces the baseline bit for bit (MuJoCo is
# deterministic); every real one here moves some observation by more than 1.
MIN_EFFECT = 0.1
CONTACT_ENVS = [e for e in SUPPORTED_ENVS if "friction" in perturbation_kinds(e)]


def _rollout(config: PerturbationConfig, n_steps: int = N_STEPS) -> np.ndarray:
    """Observations under one fixed seeded action sequence; episodes restart with the same seed."""
    env = make_perturbed_env(config)
    actions = np.random.default_rng(1).uniform(-1, 1, (n_steps, *env.action_space.shape))
    obs, _ = env.reset(seed=0)
    trajectory = [obs]
    for action in actions:
        obs, _, terminated, truncated, _ = env.step(action)
        trajectory.append(obs)
        if terminated or truncated:
            env.reset(seed=0)
    env.close()
    return np.asarray(trajectory)


@pytest.fixture(autouse=True)
def _keep_mujoco_log_out_of_the_repo(tmp_path, monkeypatch):
    """MuJoCo appends its warnings (unstable sims, deprecated settotalmass) to ./MUJOCO_LOG.TXT."""
    monkeypatch.chdir(tmp_path)


@cache
def _baseline(env_id: str) -> np.ndarray:
    return _rollout(PerturbationConfig(env_id))


@pytest.mark.parametrize("env_id,kind", [(e, k) for e in SUPPORTED_ENVS for k in perturbation_kinds(e)])
def test_every_perturbation_changes_the_trajectory(env_id, kind):
    config = sample_config(env_id, np.random.default_rng(0), kinds=[kind])
    assert config.kinds == [kind]
    perturbed = _rollout(config)
    assert np.all(np.isfinite(perturbed))
    assert np.abs(perturbed - _baseline(env_id)).max() > MIN_EFFECT, config.describe()


@pytest.mark.parametrize("env_id", SUPPORTED_ENVS)
def test_wind_itself_acts_not_only_the_medium(env_id):
    medium = PerturbationConfig(env_id, density=None if env_id == "Swimmer-v5" else 1.2)
    windy = PerturbationConfig(env_id, density=medium.density, wind=(1.0, 0.0, 0.0))
    # Weakest case, Walker2d (24 kg) in air: ~4e-3; no wind effect at all gives exactly 0.
    assert np.abs(_rollout(windy) - _rollout(medium)).max() > 1e-3


@pytest.mark.parametrize("env_id", CONTACT_ENVS)
def test_low_friction_acts_because_the_floor_is_scaled_too(env_id):
    config = PerturbationConfig(env_id, friction_scale=0.1)
    assert np.abs(_rollout(config) - _baseline(env_id)).max() > MIN_EFFECT


def test_edits_persist_across_reset():
    config = PerturbationConfig("HalfCheetah-v5", gravity=(0.0, 0.0, -2.0), friction_scale=3.0)
    env = make_perturbed_env(config)
    model = env.unwrapped.model
    friction = model.geom_friction[:, 0].copy()
    for seed in range(2):
        env.reset(seed=seed)
        env.step(env.action_space.sample())
    np.testing.assert_array_equal(model.opt.gravity, [0.0, 0.0, -2.0])
    np.testing.assert_array_equal(model.geom_friction[:, 0], friction)
    default = make_perturbed_env(PerturbationConfig("HalfCheetah-v5")).unwrapped.model
    np.testing.assert_allclose(friction, 3.0 * default.geom_friction[:, 0])  # the floor (geom 0) included


# ---------------------------------------------------------------------------- geometry

# part -> (geoms it must stretch, a geom it must leave alone); a geom is named, or "body:NAME"
# for the first geom of an unnamed-geom body (Swimmer).
GEOMETRY_CASES = [
    ("HalfCheetah-v5", "bshin", ["bshin"], "bthigh"),
    ("Ant-v5", "front_left_leg", ["aux_1_geom", "left_leg_geom", "left_ankle_geom"], "right_leg_geom"),
    ("Walker2d-v5", "left_leg", ["thigh_left_geom", "leg_left_geom", "foot_left_geom"], "thigh_geom"),
    ("Swimmer-v5", "mid", ["body:mid"], "body:back"),
]


def _geom_id(model, name: str) -> int:
    if name.startswith("body:"):
        return int(model.body_geomadr[model.body(name[5:]).id])
    return model.geom(name).id


@pytest.mark.parametrize("env_id,part,stretched,unchanged", GEOMETRY_CASES)
def test_geometry_scaling_stretches_only_the_part(env_id, part, stretched, unchanged):
    assert part in geometry_parts(env_id)
    original = make_perturbed_env(PerturbationConfig(env_id)).unwrapped.model
    scaled = make_perturbed_env(PerturbationConfig(env_id, geometry_scales={part: 2.0})).unwrapped.model
    # MjSpec.to_xml writes 6 significant digits: compare to that precision.
    for name in stretched:
        g0, g1 = _geom_id(original, name), _geom_id(scaled, name)
        length, radius = scaled.geom_size[g1, 1], scaled.geom_size[g1, 0]
        assert length == pytest.approx(2.0 * original.geom_size[g0, 1], rel=1e-5), name
        assert radius == pytest.approx(original.geom_size[g0, 0], rel=1e-5), name
    g0, g1 = _geom_id(original, unchanged), _geom_id(scaled, unchanged)
    np.testing.assert_allclose(scaled.geom_size[g1], original.geom_size[g0], rtol=1e-5)
    # Same density: the torso keeps its mass (also HalfCheetah's, despite settotalmass), the robot gains.
    assert scaled.body("torso").mass[0] == pytest.approx(original.body("torso").mass[0], rel=1e-5)
    assert scaled.body_subtreemass[0] > original.body_subtreemass[0]


def _max_penetration(env, n_steps: int) -> float:
    """Deepest robot-floor overlap (m) from reset through n_steps of zero action."""
    data, worst = env.unwrapped.data, 0.0
    env.reset(seed=0)
    for step in range(n_steps + 1):
        if step:
            env.step(np.zeros(env.action_space.shape))
        worst = max([worst] + [-c.dist for c in data.contact[: data.ncon]])
    return worst


@pytest.mark.parametrize("env_id", CONTACT_ENVS)
def test_longest_legs_do_not_start_inside_the_floor(env_id):
    parts = geometry_parts(env_id)[:1] if env_id == "Walker2d-v5" else geometry_parts(env_id)
    config = PerturbationConfig(env_id, geometry_scales={p: 2.5 for p in parts})
    env = make_perturbed_env(config)
    # Without the torso lift these overlaps are 0.11 m (Ant) to 1.4 m (Walker2d); unscaled <= 0.013 m.
    assert _max_penetration(env, n_steps=5) < 0.05
    env.reset(seed=0)
    _, _, terminated, _, _ = env.step(np.zeros(env.action_space.shape))
    assert not terminated  # healthy_z_range follows the longer legs


# ----------------------------------------------------------------------- configuration


def test_seeded_sampling_is_reproducible_non_empty_and_in_range():
    ranges = PerturbationRanges()
    for env_id in SUPPORTED_ENVS:
        configs = [sample_config(env_id, np.random.default_rng(s)) for s in range(40)]
        assert configs == [sample_config(env_id, np.random.default_rng(s)) for s in range(40)]
        assert len({c.to_json() for c in configs}) == len(configs)
        assert all(c.kinds for c in configs)
        assert set().union(*(c.kinds for c in configs)) == set(perturbation_kinds(env_id))
        for c in configs:
            if c.gravity is not None:
                assert ranges.gravity[0] <= -c.gravity[2] <= ranges.gravity[1]
                assert (c.gravity[0] != 0) == (env_id == "Swimmer-v5")  # z-gravity cannot act on Swimmer
            if c.wind is not None:
                assert ranges.wind_speed[0] <= math.hypot(*c.wind) <= ranges.wind_speed[1]
            if c.friction_scale is not None:
                assert ranges.friction_scale[0] <= c.friction_scale <= ranges.friction_scale[1]
            if c.geometry_scales:
                low, high = ranges.geometry_scale
                assert all(low <= v <= high for v in c.geometry_scales.values())
                expected = 1 if env_id == "Walker2d-v5" else len(geometry_parts(env_id))
                assert len(c.geometry_scales) == expected


def test_config_json_round_trip_is_exact():
    for env_id in SUPPORTED_ENVS:
        for seed in range(5):
            config = sample_config(env_id, np.random.default_rng(seed))
            text = config.to_json()
            assert PerturbationConfig.from_json(text) == config
            assert PerturbationConfig.from_json(text).to_json() == text
            assert json.loads(text)["env_id"] == env_id
            assert config.describe().startswith(env_id)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"gravity": (4.0, 0.5)},
        {"gravity": (0.0, 4.0)},
        {"gravity": (1.0, math.inf)},
        {"wind_speed": (-1.0, 1.0)},
        {"friction_scale": (0.0, 50.0)},
        {"friction_scale": (50.0, 0.1)},
        {"geometry_scale": (-1.5, 2.5)},
        {"geometry_scale": (1.5,)},
        {"wind_density": 0.0},
    ],
)
def test_invalid_ranges_raise(kwargs):
    with pytest.raises(ValueError, match="PerturbationRanges"):
        PerturbationRanges(**kwargs)


def test_unsupported_env_raises_and_lists_the_supported_ones():
    for call in (
        lambda: sample_config("Hopper-v5", np.random.default_rng(0)),
        lambda: PerturbationConfig("Hopper-v5"),
        lambda: perturbation_kinds("Hopper-v5"),
    ):
        with pytest.raises(ValueError, match="HalfCheetah-v5.*Swimmer-v5"):
            call()


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"env_id": "Swimmer-v5", "friction_scale": 2.0}, "no contacts"),
        ({"env_id": "Ant-v5", "geometry_scales": {"tail": 2.0}}, "Unknown geometry part"),
        ({"env_id": "Ant-v5", "geometry_scales": {"back_leg": -2.0}}, "must be > 0"),
        ({"env_id": "Ant-v5", "gravity": (0.0, -1.0)}, "3 finite numbers"),
    ],
)
def test_invalid_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PerturbationConfig(**kwargs)


def test_sampling_rejects_kinds_the_env_lacks():
    with pytest.raises(ValueError, match="non-empty subset"):
        sample_config("Swimmer-v5", np.random.default_rng(0), kinds=["friction"])


# ------------------------------------------------------------------------- stability


def test_is_unstable():
    assert not is_unstable(np.array([0.1, -20.0, 3.0]))
    assert is_unstable(np.array([0.1, np.nan]))
    assert is_unstable(np.array([np.inf, 0.0]))
    assert is_unstable(np.array([1e30, 0.0]))


def test_stable_sampling_keeps_a_stable_first_draw():
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnstablePerturbationWarning)
        config = sample_stable_config("HalfCheetah-v5", np.random.default_rng(0), probe_steps=50)
    assert config == sample_config("HalfCheetah-v5", np.random.default_rng(0))


def test_stable_sampling_reports_each_rejection_and_gives_up():
    # Ant's geoms have density 5: in a medium of 1000 kg/m^3 (water) it blows up at once.
    ranges = PerturbationRanges(wind_density=1000.0)
    with pytest.warns(UnstablePerturbationWarning, match="Rejected Ant-v5") as record:
        with pytest.raises(RuntimeError, match="No stable perturbation of Ant-v5 in 3 tries"):
            sample_stable_config(
                "Ant-v5", np.random.default_rng(0), ranges, probe_steps=20, max_tries=3, kinds=["wind"]
            )
    assert len([w for w in record if w.category is UnstablePerturbationWarning]) == 3


# ----------------------------------------------------------------------- physical ranges


@pytest.mark.parametrize(
    "kwargs",
    [
        {"friction_scale": 1e6},
        {"gravity": (0.0, 0.0, 50.0)},  # upwards
        {"gravity": (0.0, 0.0, -9.81)},  # stronger than the paper's 0.5-4 m/s^2
        {"geometry_scales": {"bthigh": 50.0}},
        {"wind": (0.0, 3.0, 0.0), "density": 1.2},
        {"density": 1000.0},
    ],
)
def test_values_outside_the_papers_ranges_need_the_explicit_flag(kwargs):
    with pytest.raises(ValueError, match="leaves the paper's ranges.*outside_ranges=True"):
        PerturbationConfig("HalfCheetah-v5", **kwargs)
    config = PerturbationConfig("HalfCheetah-v5", **kwargs, outside_ranges=True)
    assert json.loads(config.to_json())["outside_ranges"] is True
    assert PerturbationConfig.from_json(config.to_json()) == config


def test_draws_from_wider_ranges_are_flagged_and_paper_draws_are_not():
    wide = PerturbationRanges(friction_scale=(100.0, 1000.0))
    config = sample_config("HalfCheetah-v5", np.random.default_rng(0), wide, kinds=["friction"])
    assert config.outside_ranges and PerturbationConfig.from_json(config.to_json()) == config
    paper = sample_config("HalfCheetah-v5", np.random.default_rng(0), kinds=["friction"])
    assert not paper.outside_ranges and "outside_ranges" not in json.loads(paper.to_json())


@pytest.mark.parametrize(
    "text,match",
    [
        ('{"env_id": "Ant-v5", "gravity": 2.0}', "gravity must be a list of 3 numbers"),
        ('{"env_id": "Ant-v5", "wind": "east"}', "wind must be a list of 3 numbers"),
        ('{"env_id": "Ant-v5", "friction_scale": "2"}', "friction_scale='2': must be a finite number"),
        ('{"env_id": "Ant-v5", "geometry_scales": {"back_leg": "x2"}}', "must be a finite number"),
        ('{"env_id": "Ant-v5", "seed": 1.5}', "seed=1.5: must be an integer"),
        ('{"env_id": "Ant-v5", "gravity": [0, 0,', "not valid JSON"),
        ('["Ant-v5"]', "Not a PerturbationConfig JSON object"),
    ],
)
def test_json_type_errors_name_the_field(text, match):
    with pytest.raises(ValueError, match=match):
        PerturbationConfig.from_json(text)
