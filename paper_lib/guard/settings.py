"""params.yaml's `guard` section -> validated settings of the guard experiment for the active profile.

    guard:
      alpha: 0.05               # false-alarm rate (per state, or per episode for the sequential guards)
      confidence: 0.9           # optional: each guard's own rate <= alpha with this probability (default: on average)
      window: 10                # sliding-window length of the window guard
      cusum_quantile: 0.9       # CUSUM drift = this quantile of held-out ID scores
      fallback: zero            # what acts while flagged
      fallback_scores: [value_std, mahalanobis_obs]   # guards whose fallback runs are measured
      combine: [value_std, mahalanobis_obs]           # a rank combination of these, where all apply
      budgets:                  # per profile; may also override alpha and window
        tiny: {alpha: 0.2, window: 3, fit_episodes: 4, calibration_episodes: 12, ...}
        paper: {..., seeds: [0]}   # optional: only these seeds of the profile's runs (default: all)

Every error is raised here, naming the key and what to write, before any rollout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from paper_lib.guard.conformal import check_alpha, check_confidence, check_window, min_calibration_size
from paper_lib.guard.scores import SCORE_NAMES
from paper_lib.pipeline.config import RunConfig, check_keys, read_params, seeds_of, validate_params

SECTION = "guard"
SHARED = ("alpha", "window", "cusum_quantile", "fallback", "fallback_scores", "combine")
BUDGET = ("fit_episodes", "calibration_episodes", "id_test_episodes", "perturbed_episodes", "episode_steps",
          "change_steps")
#: Keys that may be left out (None): confidence None is the marginal guarantee.
OPTIONAL = ("confidence",)
FALLBACKS = ("zero",)


@dataclass(frozen=True)
class GuardSettings:
    """The experiment's settings for one profile."""

    profile: str
    alpha: float
    window: int
    cusum_quantile: float
    fallback: str
    fallback_scores: tuple[str, ...]
    combine: tuple[str, ...]
    fit_episodes: int  # ID episodes to fit the detectors (half) and to set the CUSUM drift / ranks (half)
    calibration_episodes: int
    id_test_episodes: int
    perturbed_episodes: int
    episode_steps: int
    change_steps: tuple[int, int]  # the change happens at a uniform step in [low, high]
    seeds: tuple[int, ...] | None = None  # the runs' seeds the experiment covers (None: all of the profile's)
    confidence: float | None = None  # each guard's own rate <= alpha with this probability (None: on average)

    def covers(self, seed: int) -> bool:
        return self.seeds is None or seed in self.seeds

    def caption(self) -> str:
        low, high = self.change_steps
        certainty = ("on average over calibration sets" if self.confidence is None else
                     f"for each guard with probability >= {self.confidence:g} over its calibration set")
        return (f"guard alpha {self.alpha:g} ({certainty}); {self.calibration_episodes} held-out ID calibration "
                f"episodes, {self.id_test_episodes} ID and {self.perturbed_episodes} perturbed test episodes of "
                f"{self.episode_steps} steps, the physics changing at a uniform step in [{low}, {high}]; window "
                f"{self.window}; CUSUM drift = {self.cusum_quantile:g} quantile of held-out ID scores"
                + ("" if self.seeds is None else f"; runs of seed(s) {', '.join(map(str, self.seeds))} only"))


def _int(value: Any, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{where} must be an integer >= {minimum}, got {value!r}")
    return value


def _names(value: Any, where: str) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{where} must be a list of score names, e.g. [value_std, mahalanobis_obs], got {value!r}")
    unknown = [v for v in value if v not in SCORE_NAMES]
    if unknown:
        raise ValueError(f"{where}: unknown score(s) {unknown}; use names from {list(SCORE_NAMES)}")
    return tuple(value)


def parse_settings(section: Any, profile: str, where: str) -> GuardSettings:
    """Validate the section and merge the profile's budget over the shared settings."""
    if not isinstance(section, dict):
        raise ValueError(f"{where} must be a mapping with {list(SHARED)} and `budgets`, got {section!r}")
    check_keys(section, where, [*SHARED, *OPTIONAL, "budgets"])
    budgets = section.get("budgets")
    if isinstance(budgets, dict) and profile in budgets and not isinstance(budgets[profile], dict):
        raise ValueError(f"{where}.budgets.{profile} must be a mapping "
                         f"{{{', '.join(f'{k}: ...' for k in BUDGET)}}}, got {budgets[profile]!r}")
    if not isinstance(budgets, dict) or profile not in budgets:
        have = sorted(budgets) if isinstance(budgets, dict) else []
        raise ValueError(f"{where}.budgets has no mapping for the active profile {profile!r} (has {have}); add "
                         f"`{profile}: {{{', '.join(f'{k}: ...' for k in BUDGET)}}}`")
    budget = budgets[profile]
    check_keys(budget, f"{where}.budgets.{profile}", [*BUDGET, "alpha", "window", "confidence", "seeds"])
    seeds = budget.get("seeds")
    if seeds is not None and not (isinstance(seeds, list) and seeds
                                  and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds)):
        raise ValueError(f"{where}.budgets.{profile}: seeds must be a non-empty list of run seeds, e.g. [0], "
                         f"or left out for all of them; got {seeds!r}")
    merged = {**{k: section.get(k) for k in SHARED + OPTIONAL}, **{k: v for k, v in budget.items() if k != "seeds"}}
    missing = [k for k in SHARED + BUDGET if merged.get(k) is None]
    if missing:
        raise ValueError(f"{where}: {missing} not set for profile {profile!r}; set them in `guard` or in its budget")
    here = f"{where} (profile {profile!r})"

    def key(name: str) -> str:
        """Where `name` was set: the profile's budget, or the shared section (named so the message points at it)."""
        return f"{where}.budgets.{profile}.{name}" if name in budget else f"{where}.{name} (profile {profile!r})"

    try:
        alpha = check_alpha(merged["alpha"])
        window = check_window(merged["window"])
        confidence = check_confidence(merged["confidence"])
    except ValueError as err:
        raise ValueError(f"{here}: {err}") from None
    quantile = merged["cusum_quantile"]
    if isinstance(quantile, bool) or not isinstance(quantile, (int, float)) or not 0 < quantile < 1:
        raise ValueError(f"{here}: cusum_quantile must lie strictly between 0 and 1, e.g. 0.9, got {quantile!r}")
    if merged["fallback"] not in FALLBACKS:
        raise ValueError(f"{here}: fallback must be one of {list(FALLBACKS)}, got {merged['fallback']!r}")
    fallback_scores = _names(merged["fallback_scores"], f"{here}: fallback_scores")
    combine = _names(merged["combine"], f"{here}: combine")
    if len(combine) == 1:
        raise ValueError(f"{here}: combine needs two or more scores (or [] for none), got {list(combine)}")
    counts = {k: _int(merged[k], key(k), 1) for k in BUDGET[:-2]}
    if counts["fit_episodes"] < 2:
        raise ValueError(f"{here}: fit_episodes must be >= 2 (half fit the detectors, half set the CUSUM drift)")
    need = min_calibration_size(alpha, confidence)
    if counts["calibration_episodes"] < need and confidence is None:
        raise ValueError(f"{here}: alpha={alpha:g} needs calibration_episodes >= {need} (n >= 1/alpha - 1), got "
                         f"{counts['calibration_episodes']}; raise it or raise alpha to >= "
                         f"{1 / (counts['calibration_episodes'] + 1):.3g}")
    if counts["calibration_episodes"] < need:
        raise ValueError(f"{here}: alpha={alpha:g} at confidence={confidence:g} needs calibration_episodes >= {need} "
                         f"(n >= log(1 - confidence) / log(1 - alpha)), got {counts['calibration_episodes']}; raise it, "
                         "lower the confidence, or leave confidence out for the guarantee on average")
    steps = _int(merged["episode_steps"], key("episode_steps"), 2)
    change = merged["change_steps"]
    if not (isinstance(change, list) and len(change) == 2 and all(isinstance(c, int) and not isinstance(c, bool)
                                                                  for c in change)
            and 0 <= change[0] <= change[1] < steps - 1):
        raise ValueError(f"{key('change_steps')} must be [low, high] with 0 <= low <= high < episode_steps - 1 = "
                         f"{steps - 1}, got {change!r}")
    if window >= steps:
        raise ValueError(f"{here}: window={window} must be shorter than episode_steps={steps}")
    return GuardSettings(profile=profile, alpha=alpha, window=window, cusum_quantile=float(quantile),
                         fallback=merged["fallback"], fallback_scores=fallback_scores, combine=combine,
                         episode_steps=steps, change_steps=(change[0], change[1]),
                         seeds=None if seeds is None else tuple(seeds), confidence=confidence, **counts)


def check_budget_seeds(section: Any, seeds_of: dict[str, list[int]], where: str) -> None:
    """Each budget's `seeds` must be seeds its profile trains: another seed has no runs, and the experiment's
    tables would be empty (notebook 8 would fail deep in pandas instead of here)."""
    budgets = section.get("budgets") if isinstance(section, dict) else None
    for profile, budget in (budgets.items() if isinstance(budgets, dict) else []):
        seeds = budget.get("seeds") if isinstance(budget, dict) else None
        if not isinstance(seeds, list) or not isinstance(seeds_of.get(profile), list):
            continue
        missing = [s for s in seeds if s not in seeds_of[profile]]
        if missing:
            raise ValueError(f"{where}.budgets.{profile}: seeds must be seeds of profile {profile!r}, got {missing} "
                             f"(its runs have seeds {seeds_of[profile]}); use some of {seeds_of[profile]} or leave "
                             "`seeds` out for all of them")


def load_settings(params_file: str | Path = "params.yaml") -> tuple[RunConfig, GuardSettings]:
    """The active profile (checked by paper_lib.pipeline.config) and its guard settings."""
    path = Path(params_file)
    params = read_params(path)  # the project's reader: syntax errors and duplicate keys named with their line
    if SECTION not in params:
        raise ValueError(f"{path} has no `{SECTION}` section; add it (see paper_lib/guard/settings.py and docs/guard.md)")
    section = params.pop(SECTION)
    cfg = validate_params(params, path)
    where = f"{path}: {SECTION}"
    settings = parse_settings(section, cfg.profile, where)
    budgets = section.get("budgets") if isinstance(section, dict) else None
    for name in sorted(set(budgets or {}) & set(params["profiles"]) - {cfg.profile}):
        parse_settings(section, name, where)  # every profile's budget, not the active one's only: `use` switches
    seeds = {name: seeds_of(profile["seeds"]) for name, profile in params["profiles"].items()
             if isinstance(profile, dict) and isinstance(profile.get("seeds"), (list, dict))}
    check_budget_seeds(section, {**seeds, cfg.profile: cfg.all_seeds}, where)
    return cfg, settings
