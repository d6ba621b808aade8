"""The search space as data: params.yaml's `study.space` entries -> Optuna distributions -> make_agent arguments.

An entry is either a list of choices or a range, as rl-baselines3-zoo writes its samplers:

    learning_rate: {low: 1.0e-05, high: 0.003, log: true}     # float, log-uniform
    dropout_p: {low: 0.05, high: 0.5, step: 0.05}              # float on a grid
    n_steps: {choices: [64, 128, 256, 512]}                     # categorical
    n_members: {low: 2, high: 8, type: int}                     # integer range

A sampled configuration is turned into make_agent's arguments in one place
(`agent_kwargs`): algorithm settings become `overrides`, the width and activation edit
the env's hyperparameter entry, and k, p and the Masksembles scale are passed as is.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import Any

import optuna

_RANGE_KEYS = ("low", "high", "log", "step", "type")


@dataclass(frozen=True)
class ParamSpec:
    """One searched setting: `choices`, or a `low`..`high` range (float or int, optionally log or stepped)."""

    name: str
    choices: tuple[Any, ...] | None = None
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None
    type: str = "float"

    def suggest(self, trial: optuna.Trial) -> Any:
        return _suggest(trial, self)

    def to_dict(self) -> dict[str, Any]:
        if self.choices is not None:
            return {"choices": list(self.choices)}
        out: dict[str, Any] = {"low": self.low, "high": self.high}
        if self.log:
            out["log"] = True
        if self.step is not None:
            out["step"] = self.step
        if self.type != "float":
            out["type"] = self.type
        return out


def _suggest(trial: optuna.Trial, spec: ParamSpec) -> Any:
    if spec.choices is not None:
        return trial.suggest_categorical(spec.name, list(spec.choices))
    if spec.type == "int":
        return trial.suggest_int(spec.name, int(spec.low), int(spec.high), log=spec.log, step=int(spec.step or 1))
    return trial.suggest_float(spec.name, float(spec.low), float(spec.high), log=spec.log, step=spec.step)


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        hint = " (YAML reads 1e-5 without a dot as text: write 1.0e-05)" if isinstance(value, str) else ""
        raise ValueError(f"{where} must be a finite number, got {value!r}{hint}")
    return value


def parse_param(name: str, raw: Any, where: str) -> ParamSpec:
    """One entry of the space, checked: one ValueError naming the entry and what to write."""
    example = "{choices: [64, 128]} or {low: 1.0e-05, high: 0.003, log: true}"
    if not isinstance(raw, dict):
        raise ValueError(f"{where} must be a mapping like {example}, got {raw!r}")
    if "choices" in raw:
        if set(raw) != {"choices"}:
            raise ValueError(f"{where}: give either `choices` or a range ({list(_RANGE_KEYS)}), not both")
        choices = raw["choices"]
        if not isinstance(choices, list) or not choices or len({repr(c) for c in choices}) != len(choices):
            raise ValueError(f"{where}.choices must be a non-empty list without repeats, got {choices!r}")
        if not all(c is None or isinstance(c, (bool, int, float, str)) for c in choices):
            raise ValueError(f"{where}.choices may hold numbers, strings and booleans only, got {choices!r}")
        return ParamSpec(name, choices=tuple(choices))
    unknown = sorted(set(raw) - set(_RANGE_KEYS))
    if unknown or not {"low", "high"} <= set(raw):
        raise ValueError(f"{where} must be like {example}; got keys {sorted(raw)}")
    kind = raw.get("type", "float")
    if kind not in ("float", "int"):
        raise ValueError(f"{where}.type={kind!r}; use float (the default) or int")
    low, high = _number(raw["low"], f"{where}.low"), _number(raw["high"], f"{where}.high")
    log = raw.get("log", False)
    if not isinstance(log, bool):
        raise ValueError(f"{where}.log must be true or false, got {log!r}")
    step = raw.get("step")
    if step is not None and _number(step, f"{where}.step") <= 0:
        raise ValueError(f"{where}.step must be positive, got {step!r}")
    if not low < high:
        raise ValueError(f"{where}: low={low} must be below high={high}")
    if log and (low <= 0 or step is not None):
        raise ValueError(f"{where}: a log range needs low > 0 and no step, got low={low}, step={step}")
    if kind == "int" and not all(isinstance(v, int) for v in (low, high, step or 1)):
        raise ValueError(f"{where}: an int range needs integer low, high and step, got {low}, {high}, {step}")
    return ParamSpec(name, low=low, high=high, log=log, step=step, type=kind)


def parse_space(raw: dict[str, Any], where: str) -> dict[str, ParamSpec]:
    return {name: parse_param(name, entry, f"{where}.{name}") for name, entry in raw.items()}


def suggest_params(trial: optuna.Trial, space: dict[str, ParamSpec]) -> dict[str, Any]:
    """Every searched setting for this trial (a retried trial gets back the values it had)."""
    return {name: spec.suggest(trial) for name, spec in space.items()}


def agent_kwargs(params: dict[str, Any], fixed: dict[str, Any], hp: dict[str, Any]) -> dict[str, Any]:
    """A configuration (sampled `params` plus the budget's `fixed` settings) -> make_agent keyword arguments.

    `hp` is the env's hyperparameter entry; a copy is edited: `width` replaces every hidden
    layer's width (for every method, Masksembles included, so the methods are compared at
    the same sampled width), `activation_fn` and `log_std_init` the policy settings. A sampled member
    count that does not divide the recipe's `n_envs` raises it to the next multiple (each member acts in
    its own env group): Walker2d's 4 envs become 8 for k = 8, so every env searches the same space.
    """
    hp = copy.deepcopy(hp)
    settings = {**params, **fixed}
    kwargs: dict[str, Any] = {"hyperparameters": hp}
    overrides = {}
    for key, value in settings.items():
        if key == "width":
            hp["hidden_sizes"] = [int(value)] * len(hp.get("hidden_sizes") or [value])
            hp.pop("hidden_sizes_masksembles", None)
        elif key in ("activation_fn", "log_std_init"):
            hp["policy"] = {**(hp.get("policy") or {}), key: value}
        elif key in ("n_members", "dropout_p", "masksembles_scale"):
            kwargs[key] = value
        else:
            overrides[key] = value
    members = kwargs.get("n_members")
    if members and hp.get("n_envs") and hp["n_envs"] % members:
        hp["n_envs"] = -(-hp["n_envs"] // members) * members
    kwargs["overrides"] = overrides
    return kwargs
