"""Physics perturbations that turn Gymnasium MuJoCo envs into OOD environments.

Paper appendix G (Table "mujoco_attacks"): a configuration is a random non-empty
subset of {gravity, wind, friction, geometry}, each drawn from a fixed range. The
scalar physics (gravity, wind, medium density, friction) is written into the live
``env.unwrapped.model``; geometry is edited with ``mujoco.MjSpec`` and recompiled so
that masses, inertias and bounding volumes stay consistent with the new shapes.

Choices the paper leaves open: wind blows through air (density 1.2) in envs whose
model has no medium, and through Swimmer's own fluid; friction factors are drawn
log-uniformly; geometry scaling makes legs longer, not thicker, at unchanged
material density; longer legs lift the torso so the robot starts on the floor.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from dataclasses import dataclass

import gymnasium as gym
import mujoco
import numpy as np

from paper_lib.agents.envs import make_single_env, model_spec, write_model_xml

SUPPORTED_ENVS: tuple[str, ...] = ("HalfCheetah-v5", "Ant-v5", "Walker2d-v5", "Swimmer-v5")
KINDS: tuple[str, ...] = ("gravity", "wind", "friction", "geometry")

# A rollout whose observation leaves this bound has exploded: none of these robots
# moves at 1e5 m/s or rad/s, while MuJoCo itself only flags values above 1e10.
_OBS_LIMIT = 1e5
_INSTABILITY_WARNINGS = (
    mujoco.mjtWarning.mjWARN_BADQPOS,
    mujoco.mjtWarning.mjWARN_BADQVEL,
    mujoco.mjtWarning.mjWARN_BADQACC,
)


class UnstablePerturbationWarning(RuntimeWarning):
    """A sampled configuration was rejected because its simulation blew up."""


@dataclass(frozen=True)
class _Part:
    """A body part that geometry scaling stretches about ``anchor`` (body frame).

    ``subtree`` stretches the body's descendants with it (a whole leg); otherwise
    only the body's own geoms grow and its children move to the new attachment
    point (one leg element, as the paper scales HalfCheetah).
    """

    body: str
    subtree: bool = False
    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class _EnvInfo:
    xml: str  # gymnasium's own asset file
    parts: dict[str, _Part]
    one_part: bool  # Walker2d: the paper scales the left OR the right leg
    planar_xz: bool  # the robot moves in the x-z plane: wind along +-x only
    contacts: bool  # False: no geom ever collides, so friction cannot act (Swimmer)
    has_medium: bool  # the model already sets a fluid density (Swimmer)
    healthy_z_range: tuple[float, float] | None = None  # gymnasium's default, if it has one

    @property
    def kinds(self) -> tuple[str, ...]:
        return KINDS if self.contacts else tuple(k for k in KINDS if k != "friction")


_ENVS: dict[str, _EnvInfo] = {
    "HalfCheetah-v5": _EnvInfo(
        xml="half_cheetah.xml",
        parts={n: _Part(n) for n in ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")},
        one_part=False,
        planar_xz=True,
        contacts=True,
        has_medium=False,
    ),
    "Ant-v5": _EnvInfo(
        xml="ant.xml",
        parts={
            n: _Part(n, subtree=True)
            for n in ("front_left_leg", "front_right_leg", "back_leg", "right_back_leg")
        },
        one_part=False,
        planar_xz=False,
        contacts=True,
        has_medium=False,
        healthy_z_range=(0.2, 1.0),
    ),
    "Walker2d-v5": _EnvInfo(
        xml="walker2d_v5.xml",
        # walker2d_v5.xml names the right leg "thigh" and its copy "thigh_left".
        parts={"right_leg": _Part("thigh", subtree=True), "left_leg": _Part("thigh_left", subtree=True)},
        one_part=True,
        planar_xz=True,
        contacts=True,
        has_medium=False,
        healthy_z_range=(0.8, 2.0),
    ),
    "Swimmer-v5": _EnvInfo(
        xml="swimmer.xml",
        # The head capsule spans x in [0.5, 1.5] of the torso frame and meets "mid"
        # at x = 0.5: scale it about that joint so the segments stay connected.
        parts={"torso": _Part("torso", anchor=(0.5, 0.0, 0.0)), "mid": _Part("mid"), "back": _Part("back")},
        one_part=False,
        planar_xz=False,
        # Every Swimmer geom has contype = conaffinity = 0: it never touches anything.
        contacts=False,
        has_medium=True,
    ),
}


def _env_info(env_id: str) -> _EnvInfo:
    if env_id not in _ENVS:
        raise ValueError(f"Unsupported env id {env_id!r}: use one of {list(SUPPORTED_ENVS)}.")
    return _ENVS[env_id]


def perturbation_kinds(env_id: str) -> list[str]:
    """Kinds of perturbation that act on ``env_id`` (Swimmer has no contacts: no friction)."""
    return list(_env_info(env_id).kinds)


def geometry_parts(env_id: str) -> list[str]:
    """Names of the body parts that geometry scaling can stretch in ``env_id``."""
    return list(_env_info(env_id).parts)


def _check_range(name: str, bounds: tuple[float, float], min_low: float, strict: bool) -> None:
    if len(bounds) != 2:
        raise ValueError(f"PerturbationRanges.{name}={bounds}: give a (low, high) pair.")
    low, high = bounds
    if not (math.isfinite(low) and math.isfinite(high)) or low > high:
        raise ValueError(f"PerturbationRanges.{name}={bounds}: need finite (low, high) with low <= high.")
    if low < min_low or (strict and low == min_low):
        sign = ">" if strict else ">="
        raise ValueError(f"PerturbationRanges.{name}={bounds}: the lower bound must be {sign} {min_low}.")


@dataclass(frozen=True)
class PerturbationRanges:
    """Sampling ranges; defaults are the paper's Table (appendix G).

    ``wind_density`` is the medium density (kg/m^3) set together with wind, because
    MuJoCo's wind only acts through a medium; 1.2 is air. Water (1000) makes Ant
    (geom density 5) blow up.
    """

    gravity: tuple[float, float] = (0.5, 4.0)  # |g| in m/s^2 (vs. 9.81 by default)
    wind_speed: tuple[float, float] = (0.0, 1.0)  # m/s
    friction_scale: tuple[float, float] = (0.1, 50.0)  # factor, drawn log-uniformly
    geometry_scale: tuple[float, float] = (1.5, 2.5)  # factor per part
    wind_density: float = 1.2

    def __post_init__(self) -> None:
        _check_range("gravity", self.gravity, 0.0, strict=True)
        _check_range("wind_speed", self.wind_speed, 0.0, strict=False)
        _check_range("friction_scale", self.friction_scale, 0.0, strict=True)
        _check_range("geometry_scale", self.geometry_scale, 0.0, strict=True)
        if not (math.isfinite(self.wind_density) and self.wind_density > 0):
            raise ValueError(
                f"PerturbationRanges.wind_density={self.wind_density}: must be > 0 (1.2 is air)."
            )


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _number(name: str, value: object) -> float:
    """A finite real number, or one ValueError naming the field (strings and booleans are not numbers)."""
    if not _is_number(value) or not math.isfinite(value):
        raise ValueError(f"PerturbationConfig.{name}={value!r}: must be a finite number.")
    return float(value)


def _vec3(name: str, value: tuple[float, ...] | None) -> tuple[float, float, float] | None:
    if value is None:
        return None
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != 3 \
            or not all(_is_number(v) and math.isfinite(v) for v in value):
        raise ValueError(f"PerturbationConfig.{name}={value!r}: give 3 finite numbers (x, y, z) or None.")
    return tuple(float(v) for v in value)  # type: ignore[return-value]


#: Relative slack on the range checks: log-uniform draws can land one rounding step past a bound.
_RANGE_SLACK = 1e-9


def _inside(value: float, bounds: tuple[float, float]) -> bool:
    low, high = bounds
    return low * (1 - _RANGE_SLACK) - _RANGE_SLACK <= value <= high * (1 + _RANGE_SLACK) + _RANGE_SLACK


def range_violations(config: PerturbationConfig, ranges: PerturbationRanges) -> list[str]:
    """How ``config`` leaves ``ranges`` (empty if it could have been drawn from them).

    Gravity points down with a strength in ``ranges.gravity`` (Swimmer's sideways pull as
    strong at most); wind blows at a speed in ``ranges.wind_speed`` through a medium no denser
    than ``ranges.wind_density``; friction and geometry factors lie in their ranges.
    """
    out = []
    if config.gravity is not None:
        gx, gy, gz = config.gravity
        if not _inside(-gz, ranges.gravity) or max(abs(gx), abs(gy)) > ranges.gravity[1] * (1 + _RANGE_SLACK):
            out.append(f"gravity={config.gravity} (downward strength in {list(ranges.gravity)} m/s^2, "
                       f"sideways at most {ranges.gravity[1]:g})")
    if config.wind is not None and not _inside(math.hypot(*config.wind), ranges.wind_speed):
        out.append(f"wind={config.wind} (speed in {list(ranges.wind_speed)} m/s)")
    if config.density is not None and not _inside(config.density, (0.0, ranges.wind_density)):
        out.append(f"density={config.density:g} (at most {ranges.wind_density:g} kg/m^3)")
    if config.friction_scale is not None and not _inside(config.friction_scale, ranges.friction_scale):
        out.append(f"friction_scale={config.friction_scale:g} (in {list(ranges.friction_scale)})")
    for part, scale in (config.geometry_scales or {}).items():
        if not _inside(scale, ranges.geometry_scale):
            out.append(f"geometry_scales[{part!r}]={scale:g} (in {list(ranges.geometry_scale)})")
    return out


@dataclass(frozen=True)
class PerturbationConfig:
    """One perturbed physics setting; ``None`` fields keep the model's default.

    ``seed`` is drawn with the configuration so that its probe rollout (and any
    ``env.reset(seed=config.seed)``) is reproducible from the config alone.

    Every value must lie in the paper's ranges (``PerturbationRanges()``, appendix G) unless
    ``outside_ranges=True`` says it is meant to leave them: friction x1e6 or gravity pulling
    upwards is a typo far more often than an experiment.
    """

    env_id: str
    gravity: tuple[float, float, float] | None = None  # m/s^2, replaces opt.gravity
    wind: tuple[float, float, float] | None = None  # m/s, replaces opt.wind
    density: float | None = None  # kg/m^3 medium density, replaces opt.density
    friction_scale: float | None = None  # multiplies every geom's sliding friction
    geometry_scales: dict[str, float] | None = None  # part name -> scale factor
    seed: int | None = None
    outside_ranges: bool = False  # True: values may leave the paper's ranges on purpose

    def __post_init__(self) -> None:
        if not isinstance(self.env_id, str):
            raise ValueError(f"PerturbationConfig.env_id={self.env_id!r}: use one of {list(SUPPORTED_ENVS)}.")
        info = _env_info(self.env_id)
        if not isinstance(self.outside_ranges, bool):
            raise ValueError(f"PerturbationConfig.outside_ranges={self.outside_ranges!r}: must be true or false.")
        object.__setattr__(self, "gravity", _vec3("gravity", self.gravity))
        object.__setattr__(self, "wind", _vec3("wind", self.wind))
        if self.density is not None:
            if not (_number("density", self.density) >= 0):
                raise ValueError(f"PerturbationConfig.density={self.density}: must be a finite number >= 0.")
            object.__setattr__(self, "density", float(self.density))
        if self.friction_scale is not None:
            if not (_number("friction_scale", self.friction_scale) > 0):
                raise ValueError(f"PerturbationConfig.friction_scale={self.friction_scale}: must be > 0.")
            object.__setattr__(self, "friction_scale", float(self.friction_scale))
        if self.seed is not None:
            if not isinstance(self.seed, (int, np.integer)) or isinstance(self.seed, bool) or self.seed < 0:
                raise ValueError(f"PerturbationConfig.seed={self.seed!r}: must be an integer >= 0 or None.")
            object.__setattr__(self, "seed", int(self.seed))
        if self.friction_scale is not None and "friction" not in info.kinds:
            raise ValueError(f"{self.env_id} has no contacts, friction cannot act: set friction_scale=None.")
        if self.geometry_scales is not None:
            if not isinstance(self.geometry_scales, dict):
                raise ValueError(f"PerturbationConfig.geometry_scales={self.geometry_scales!r}: give a mapping "
                                 f"part -> factor, e.g. {{{list(info.parts)[0]!r}: 2.0}}.")
            unknown = set(self.geometry_scales) - set(info.parts)
            if unknown:
                raise ValueError(
                    f"Unknown geometry part(s) {sorted(unknown, key=str)} for {self.env_id}: use {list(info.parts)}."
                )
            scales = {k: _number(f"geometry_scales[{k!r}]", v) for k, v in self.geometry_scales.items()}
            if not all(v > 0 for v in scales.values()):
                raise ValueError(f"PerturbationConfig.geometry_scales={scales}: factors must be > 0.")
            object.__setattr__(self, "geometry_scales", scales)
        if not self.outside_ranges:
            wrong = range_violations(self, PerturbationRanges())
            if wrong:
                raise ValueError(f"PerturbationConfig for {self.env_id}: {'; '.join(wrong)} leaves the paper's "
                                 "ranges (PerturbationRanges, appendix G); fix the value, or pass "
                                 "outside_ranges=True if you mean it.")

    @property
    def kinds(self) -> list[str]:
        """Perturbation kinds this configuration changes."""
        used = {
            "gravity": self.gravity is not None,
            "wind": self.wind is not None or self.density is not None,
            "friction": self.friction_scale is not None,
            "geometry": bool(self.geometry_scales),
        }
        return [k for k in KINDS if used[k]]

    def to_json(self) -> str:
        data = dataclasses.asdict(self)
        if not self.outside_ranges:  # the flag is written only when set: in-range JSON stays as it was
            del data["outside_ranges"]
        return json.dumps(data, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> PerturbationConfig:
        try:
            data = json.loads(text)
        except (json.JSONDecodeError, TypeError) as err:
            raise ValueError(f"PerturbationConfig JSON is not valid JSON ({err}): {str(text)[:200]!r}") from None
        fields = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(data, dict) or set(data) - fields or "env_id" not in data:
            raise ValueError(
                f"Not a PerturbationConfig JSON object (expected keys {sorted(fields)}): {text[:200]!r}"
            )
        for key in ("gravity", "wind"):
            if data.get(key) is not None:
                if not isinstance(data[key], list):
                    raise ValueError(f"PerturbationConfig JSON: {key} must be a list of 3 numbers [x, y, z] or "
                                     f"null, got {data[key]!r}")
                data[key] = tuple(data[key])
        return cls(**data)

    def describe(self) -> str:
        parts = []
        if self.gravity is not None:
            parts.append("gravity ({:.2f}, {:.2f}, {:.2f}) m/s^2".format(*self.gravity))
        if self.wind is not None or self.density is not None:
            wind = "({:.2f}, {:.2f}, {:.2f}) m/s".format(*self.wind) if self.wind else "none"
            medium = f"{self.density:g} kg/m^3" if self.density is not None else "the model's medium"
            parts.append(f"wind {wind} in {medium}")
        if self.friction_scale is not None:
            parts.append(f"friction x{self.friction_scale:.3g}")
        if self.geometry_scales:
            parts.append("geometry " + ", ".join(f"{k} x{v:.2f}" for k, v in self.geometry_scales.items()))
        return f"{self.env_id}: " + ("; ".join(parts) if parts else "unperturbed")


def sample_config(
    env_id: str,
    rng: np.random.Generator,
    ranges: PerturbationRanges = PerturbationRanges(),
    kinds: list[str] | None = None,
) -> PerturbationConfig:
    """Draw a configuration: a uniformly random non-empty subset of ``kinds`` (all by default)."""
    info = _env_info(env_id)
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be np.random.default_rng(seed), a numpy Generator; got {type(rng)}.")
    if not isinstance(ranges, PerturbationRanges):
        raise TypeError(f"ranges must be a PerturbationRanges, got {type(ranges)}.")
    kinds = list(info.kinds) if kinds is None else list(kinds)
    bad = [k for k in kinds if k not in info.kinds]
    if not kinds or bad:
        raise ValueError(f"kinds={kinds} for {env_id}: give a non-empty subset of {list(info.kinds)}.")

    # Bits of an integer in [1, 2^n) pick each non-empty subset with equal probability.
    mask = int(rng.integers(1, 2 ** len(kinds)))
    chosen = {k for i, k in enumerate(kinds) if mask >> i & 1}
    cfg: dict = {"env_id": env_id}
    if "gravity" in chosen:
        g = float(rng.uniform(*ranges.gravity))
        # Swimmer lies in the x-y plane, where z-gravity cannot act: pull along x too.
        gx = float(rng.choice([-1.0, 1.0]) * rng.uniform(*ranges.gravity)) if env_id == "Swimmer-v5" else 0.0
        cfg["gravity"] = (gx, 0.0, -g)
    if "wind" in chosen:
        speed = float(rng.uniform(*ranges.wind_speed))
        if info.planar_xz:  # head- or tailwind: the only horizontal direction these robots feel
            cfg["wind"] = (float(rng.choice([-1.0, 1.0])) * speed, 0.0, 0.0)
        else:
            angle = float(rng.uniform(0.0, 2 * math.pi))
            cfg["wind"] = (speed * math.cos(angle), speed * math.sin(angle), 0.0)
        cfg["density"] = None if info.has_medium else ranges.wind_density
    if "friction" in chosen:
        low, high = np.log(ranges.friction_scale)
        cfg["friction_scale"] = float(np.exp(rng.uniform(low, high)))
    if "geometry" in chosen:
        names = list(info.parts)
        if info.one_part:
            names = [names[int(rng.integers(len(names)))]]
        cfg["geometry_scales"] = {n: float(rng.uniform(*ranges.geometry_scale)) for n in names}
    cfg["seed"] = int(rng.integers(0, 2**31 - 1))
    # Ranges wider than the paper's are the caller's explicit choice: their draws may leave the paper's.
    cfg["outside_ranges"] = bool(range_violations(PerturbationConfig(**cfg, outside_ranges=True), PerturbationRanges()))
    return PerturbationConfig(**cfg)


# ---------------------------------------------------------------------------- geometry


def _scale_body(body: mujoco.MjsBody, scale: float, anchor: np.ndarray, subtree: bool) -> None:
    """Stretch one body's contents about ``anchor`` (its own frame) by ``scale``.

    Positions (geoms, joints, sites, child bodies) and capsule lengths scale; capsule
    radii stay, so a leg gets longer, not fatter (its mass grows with its length).
    """

    def move(p: np.ndarray) -> np.ndarray:
        return anchor + scale * (np.asarray(p) - anchor)

    for geom in body.geoms:
        if not np.isnan(geom.fromto[0]):  # the compiler derives length and position from fromto
            geom.fromto = np.concatenate([move(geom.fromto[:3]), move(geom.fromto[3:])])
            continue
        geom.pos = move(geom.pos)
        size = np.asarray(geom.size, dtype=float).copy()
        if geom.type in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
            size[1] *= scale  # half-length only
        else:
            size *= scale
        geom.size = size
    for joint in body.joints:
        joint.pos = move(joint.pos)
    for site in body.sites:
        site.pos = move(site.pos)
    for child in body.bodies:
        child.pos = move(child.pos)
        if subtree:
            _scale_body(child, scale, np.zeros(3), subtree=True)


def _lowest_point(model: mujoco.MjModel) -> float:
    """Lowest world z of any robot geom at the initial pose, joints moved into their limits.

    Ant's qpos0 has its ankles at 0, outside their 30-70 degree range: the limits
    swing the legs down at the first step, so that is the pose that must fit.
    """
    data = mujoco.MjData(model)
    one_dof = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
    for j in np.flatnonzero(model.jnt_limited):
        if int(model.jnt_type[j]) in one_dof:
            adr = model.jnt_qposadr[j]
            data.qpos[adr] = np.clip(data.qpos[adr], *model.jnt_range[j])
    mujoco.mj_forward(model, data)
    low = np.inf
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0:  # the floor and other world geoms
            continue
        z, rot, size = data.geom_xpos[g, 2], data.geom_xmat[g].reshape(3, 3), model.geom_size[g]
        kind = int(model.geom_type[g])
        if kind == int(mujoco.mjtGeom.mjGEOM_SPHERE):
            bottom = z - size[0]
        elif kind == int(mujoco.mjtGeom.mjGEOM_CAPSULE):
            bottom = z - size[0] - size[1] * abs(rot[2, 2])
        else:  # oriented bounding box from the compiled local AABB
            center, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
            bottom = z + rot[2] @ center - np.abs(rot[2]) @ half
        low = min(low, bottom)
    return float(low)


def _scaled_spec(config: PerturbationConfig) -> mujoco.MjSpec:
    """Model spec with the config's parts stretched and the torso lifted to fit.

    Mass and inertia follow from recompiling with unchanged geom densities.
    Lift: the torso (root body) is raised until the lowest robot point at the
    initial pose is as high above the floor as in the original model, so a longer
    leg does not start inside the floor. For Walker2d the ``rootz`` slide joint's
    ``ref`` moves with it, so qpos[1] stays the torso's world height (its health
    check reads it). Swimmer never touches the floor and is not lifted.
    """
    info = _env_info(config.env_id)
    spec = model_spec(config.env_id)
    original_low = _lowest_point(spec.compile())
    for name, scale in (config.geometry_scales or {}).items():
        part = info.parts[name]
        _scale_body(spec.body(part.body), scale, np.asarray(part.anchor, dtype=float), part.subtree)

    lift = max(0.0, original_low - _lowest_point(spec.compile())) if info.contacts else 0.0
    if lift > 0:
        torso = spec.body("torso")
        torso.pos = np.asarray(torso.pos) + np.array([0.0, 0.0, lift])
        for joint in torso.joints:
            is_rootz = joint.type == mujoco.mjtJoint.mjJNT_SLIDE and np.allclose(joint.axis, [0, 0, 1])
            if is_rootz and joint.ref != 0:  # Walker2d: qpos[1] reads as world height
                joint.ref += lift
    return spec


def make_perturbed_env(config: PerturbationConfig, **gym_kwargs) -> gym.Env:
    """``gym.make`` the config's env with its physics perturbed.

    Edits of ``env.unwrapped.model`` persist across ``reset()``. With geometry
    scaling, the upper bound of Ant's and Walker2d's ``healthy_z_range`` is
    multiplied by the largest scale (unless you pass ``healthy_z_range``): a robot
    standing on longer legs would otherwise count as unhealthy at its first step.
    """
    if not isinstance(config, PerturbationConfig):
        raise TypeError(f"config must be a PerturbationConfig, got {type(config)}.")
    if config.geometry_scales:
        if "xml_file" in gym_kwargs:
            raise ValueError("Geometry scaling writes its own model: drop xml_file or geometry_scales.")
        gym_kwargs["xml_file"] = write_model_xml(_scaled_spec(config))
        healthy = _env_info(config.env_id).healthy_z_range
        if healthy is not None and "healthy_z_range" not in gym_kwargs:
            gym_kwargs["healthy_z_range"] = (healthy[0], healthy[1] * max(config.geometry_scales.values()))
    env = make_single_env(config.env_id, **gym_kwargs)
    model = env.unwrapped.model
    if config.gravity is not None:
        model.opt.gravity[:] = config.gravity
    if config.wind is not None:
        model.opt.wind[:] = config.wind
    if config.density is not None:
        model.opt.density = config.density
    if config.friction_scale is not None:
        # MuJoCo uses the larger friction of two touching geoms: scale the floor too.
        model.geom_friction[:, 0] *= config.friction_scale
    return env


# ------------------------------------------------------------------------- stability


def is_unstable(obs: np.ndarray) -> bool:
    """True if an observation holds NaN/inf or has exploded beyond physical values."""
    obs = np.asarray(obs, dtype=float)
    return bool(not np.all(np.isfinite(obs)) or np.max(np.abs(obs), initial=0.0) > _OBS_LIMIT)


def _instability(config: PerturbationConfig, probe_steps: int) -> str | None:
    """Why a short seeded random rollout of ``config`` is unstable, or None if it is not.

    MuJoCo resets the state by itself when accelerations blow up, so NaN may never
    reach the observation: its warning counters are checked after every step too.
    """
    env = make_perturbed_env(config)
    try:
        obs, _ = env.reset(seed=config.seed)
        env.action_space.seed(config.seed)
        data = env.unwrapped.data
        for step in range(probe_steps):
            obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if is_unstable(obs):
                return f"non-finite or exploding observation at step {step}"
            for warning in _INSTABILITY_WARNINGS:
                if data.warning[warning].number > 0:
                    return f"MuJoCo {warning.name} (simulation unstable) at step {step}"
            if terminated or truncated:
                env.reset()
    finally:
        env.close()
    return None


def sample_stable_config(
    env_id: str,
    rng: np.random.Generator,
    ranges: PerturbationRanges = PerturbationRanges(),
    probe_steps: int = 200,
    max_tries: int = 20,
    kinds: list[str] | None = None,
) -> PerturbationConfig:
    """``sample_config`` that rejects configs whose probe rollout goes unstable.

    Each rejection is reported with an ``UnstablePerturbationWarning``; after
    ``max_tries`` rejections a RuntimeError says to narrow the ranges.
    """
    _env_info(env_id)
    if probe_steps < 1 or max_tries < 1:
        raise ValueError(f"probe_steps={probe_steps}, max_tries={max_tries}: both must be >= 1.")
    reasons = []
    for _ in range(max_tries):
        config = sample_config(env_id, rng, ranges, kinds)
        reason = _instability(config, probe_steps)
        if reason is None:
            return config
        reasons.append(reason)
        warnings.warn(
            f"Rejected {config.describe()} (seed {config.seed}): {reason}; resampling.",
            UnstablePerturbationWarning,
            stacklevel=2,
        )
    raise RuntimeError(
        f"No stable perturbation of {env_id} in {max_tries} tries (last: {reasons[-1]}). "
        f"Narrow the PerturbationRanges (e.g. lower wind_density or friction_scale) or raise max_tries."
    )
