"""The paper's claims, each checked on our tables: one row per (claim, env) with a verdict and its numbers.

Issue 10 asks for "an honest reading": which of the paper's claims hold here and which do not. Every row carries
the numbers it rests on, so a reader can disagree with a rule without re-running anything. The rules, margins,
families and seed counts are pre-registered in params.yaml's `preregistration` (docs/preregistration.md, issue 66)
and read through `ClaimDesign`; its defaults here are the registered values (a test keeps the two equal).

The claims that rest on an interval share one rule shape (`decide`), the same burden of proof either way:
"holds" when the 95% interval excludes failure, "does not hold" when it excludes success, otherwise undecided. A
cell of one training seed is undecided whatever its interval: that interval covers the episodes or states of one
run, not the method. Where one of m cells alone would decide (some cell beats the detector; some pair is behind),
that cell's interval is simultaneous over the m (Bonferroni, the tables' `family_ci_*`), so that m chances do not
tilt the verdict that way. An undecided cell reads "provisional (k of n seeds)" while its env has fewer than its
planned seeds, "undecidable at n seeds (needs about m)" where the registered power analysis
(data/preregistration/power.csv) sized it beyond the plan, and "inconclusive (n seeds)" otherwise; a decided cell
of an env still short of its seeds reads "holds, provisional (k of n seeds)". A cell whose runs have fewer
distinct OOD conditions than a cluster bootstrap needs reads "not testable". Notebook 6 writes the table
(`tables/paper_claims`) and scripts/readme_results.py pastes it into docs/results.md.

History, told straight (each change is in git; the numbers each rule judged existed before it):
- 2026-11-22 (7c6d5b3, issue 10): first rules, fixed in code before notebook 6 read the tables.
- 2026-11-27 (3b42a3f, issue 36): one interval rule for every claim, intervals over seeds at least Student's t,
  "keeps the reward" as non-inferiority with a 10% margin. Both the margin and the rule were chosen after the
  3-seed MuJoCo and 1-seed Atari numbers existed; they made verdicts harder to reach, not easier.
- 2026-11-30 (ed10d99): simultaneous (Bonferroni) intervals where one of several cells decides, after a reading
  of Ant's detector claim as "holds" on 1 of 12 cells; conservative again (that cell became inconclusive).
- 2026-12-02 (issue 66): pre-registration before any run of the new seeds (Atari 1-2, MuJoCo 3-4) landed its
  scores: the values above moved into params.yaml with the planned seeds and the power analysis; intervals for
  the Jensen-Shannon and spawn claims (point readings before); "not testable" for too few OOD conditions;
  the reward evidence names a significant loss inside the margin; Atari and MuJoCo apart in the JS claim.
- 2026-12-05 (issue 70): the paper's speed claim (section 4), registered in params.yaml `preregistration.speed`
  before any benchmark run recorded its repetitions (`speed_claim`); it reads "not testable" until one is committed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy.stats import norm, t as student_t

from paper_lib.scoring.statistics import cell_rng

HOLDS, FAILS, MIXED, UNTESTED = "holds", "does not hold", "mixed", "not testable yet"
#: The registered values (params.yaml `preregistration`); `ClaimDesign.from_preregistration` reads them from there.
LEVEL = 0.95
#: "Keeps the baseline's reward" fails on a loss larger than this share of the baseline's reward (sampled actions).
REWARD_MARGIN = 0.10
#: "Ranks like policy std": Spearman's rho of the two measures' AUROCs at least this, per env family.
JS_THRESHOLD = 0.9
#: A run with fewer distinct OOD conditions (clusters) than this cannot carry a cluster bootstrap: 3 clusters give
#: 10 distinct resamples, 5 give 126, the least that resolves a 95% percentile interval.
MIN_OOD_CONDITIONS = 5
#: The paper's AUROC-order claim: each of these methods against each of the MC methods.
AHEAD, BEHIND = ("masksembles", "ensemble"), ("mc_dropout", "mc_dropconnect")
AUROC_ORDER_PAIRS = [(a, b) for a in AHEAD for b in BEHIND]
SPAWN_METHODS = ("masksembles", "mc_dropout", "mc_dropconnect", "ensemble")
CLAIMS = {
    "masksembles_reward": "Masksembles keeps the baseline's reward (section 5)",
    "auroc_order": "Masksembles and Ensembles detect OOD better than MC Dropout and MC DropConnect (Table 2)",
    "levitation": "Ant: value uncertainty flags detachment from the floor at spawn (section 6)",
    "js_like_std": "The Jensen-Shannon measure ranks the methods like policy std (appendix D)",
    "speed": "Masksembles infers faster than MC Dropout and trains comparably (section 4)",
    "members_vs_detectors": "(ours) The agent's own uncertainty beats the best member-free detector on the same states",
    "members_vs_pedm": "(ours) The agents' own uncertainty beats PEDM on PEDM's protocol",
}
CLAIM_KEYS = {text: key for key, text in CLAIMS.items()}
COLUMNS = ["claim", "env", "verdict", "evidence"]
SPREAD_MEASURES = ("value_std", "policy_std")
#: The speed claim's registered timings, margin and repetitions (params.yaml `preregistration.speed`).
SPEED_INFERENCE = ("act_uncertainty_b1", "uncertainty_b4096")
SPEED_TRAINING = "train_steps_per_s"
SPEED_MARGIN = 0.10
SPEED_MIN_REPETITIONS = 5


@dataclass(frozen=True)
class ClaimDesign:
    """What the rules read from the pre-registration: margins, levels, planned seeds, the power table.

    The defaults are the registered values with no seed plan (no "provisional" or "undecidable" labels): what a
    unit test of one rule needs. Notebook 6 builds it with `from_preregistration`.
    """
    level: float = LEVEL
    reward_margin: float = REWARD_MARGIN
    js_threshold: float = JS_THRESHOLD
    min_ood_conditions: int = MIN_OOD_CONDITIONS
    planned_seeds: dict[str, int] = field(default_factory=dict)  # per env family (MuJoCo, Atari): the plan
    seeds_needed: dict[tuple[str, str], float] = field(default_factory=dict)  # (claim key, env): count, inf: over
    speed_inference: tuple[str, ...] = SPEED_INFERENCE
    speed_training: str = SPEED_TRAINING
    speed_margin: float = SPEED_MARGIN
    speed_min_repetitions: int = SPEED_MIN_REPETITIONS

    @classmethod
    def from_preregistration(cls, prereg, power: pd.DataFrame) -> ClaimDesign:
        """From `reporting.preregistration.Preregistration` and its committed power table."""
        from paper_lib.reporting.preregistration import registered_counts

        return cls(level=prereg.level, reward_margin=prereg.reward_margin, js_threshold=prereg.js_threshold,
                   min_ood_conditions=prereg.min_ood_conditions,
                   planned_seeds={family: len(seeds) for family, seeds in prereg.planned_seeds.items()},
                   seeds_needed=registered_counts(power), speed_inference=tuple(prereg.speed["inference"]),
                   speed_training=prereg.speed["training"], speed_margin=prereg.speed["margin"],
                   speed_min_repetitions=prereg.speed["min_repetitions"])

    def planned(self, env: str) -> int | None:
        """The seeds `env` (or an env family's name) waits for; None without a plan."""
        from paper_lib.agents.envs import is_atari

        family = env if env in ("MuJoCo", "Atari") else "Atari" if is_atari(env) else "MuJoCo"
        return self.planned_seeds.get(family)


def inconclusive(n_seeds: int) -> str:
    return f"inconclusive ({n_seeds} seed{'' if n_seeds == 1 else 's'})"


def not_testable(conditions: int, minimum: int) -> str:
    return f"not testable ({conditions} distinct OOD conditions; needs at least {minimum})"


def decide(ci_low: float, ci_high: float, failure_below: float, n_seeds: int) -> str:
    """The one rule: success is a difference at or above `failure_below`, failure one below it.

    Holds when the interval excludes failure (ci_low >= failure_below), does not hold when it excludes
    success (ci_high < failure_below), inconclusive otherwise or with fewer than 2 seeds.
    """
    if n_seeds < 2:
        return inconclusive(n_seeds)
    if ci_low >= failure_below:
        return HOLDS
    if ci_high < failure_below:
        return FAILS
    return inconclusive(n_seeds)


def combine(verdicts: list[str], n_seeds: int) -> str:
    """Several verdicts of one claim (e.g. per measure): holds if all hold, does not hold if all fail."""
    if not verdicts:
        return UNTESTED
    if all(v == HOLDS for v in verdicts):
        return HOLDS
    if all(v == FAILS for v in verdicts):
        return FAILS
    if HOLDS in verdicts and FAILS in verdicts:
        return MIXED
    return inconclusive(n_seeds)


def staged(verdict: str, claim: str, env: str, n_seeds: int, design: ClaimDesign) -> str:
    """The verdict as the seed plan reads it: provisional while `env` has fewer than its planned seeds; an undecided
    cell at the plan is "undecidable" where the registered power analysis sized it beyond the plan."""
    planned = design.planned(env)
    if planned is None or verdict.startswith("not testable") or verdict == UNTESTED:
        return verdict
    undecided = verdict.startswith("inconclusive")
    if n_seeds < planned:
        return f"{'inconclusive' if undecided else verdict}, provisional ({n_seeds} of {planned} seeds)"
    needed = design.seeds_needed.get((claim, env))
    if undecided and needed is not None and needed > planned:
        return f"undecidable at {planned} seeds (needs {'over 200' if np.isinf(needed) else f'about {needed:.0f}'})"
    return verdict


def _row(claim: str, env: str, verdict: str, evidence: str, n_seeds: int, design: ClaimDesign) -> dict[str, str]:
    return {"claim": CLAIMS[claim], "env": env, "verdict": staged(verdict, claim, env, n_seeds, design),
            "evidence": evidence}


def reward_claim(vs_baseline: pd.DataFrame, design: ClaimDesign = ClaimDesign()) -> list[dict[str, str]]:
    """Per env, non-inferiority: Masksembles (combined) minus the baseline, sampled actions as the paper's Table 1.

    Failure is a loss larger than the margin (a share of the baseline's reward), on the paired per-seed
    difference and its interval (`paper_tables.reward_vs_baseline`). An undecided cell whose interval lies below 0
    says so: a significant loss whose size the margin cannot settle is not "no evidence".
    """
    rows = []
    cells = vs_baseline[(vs_baseline.method == "masksembles") & (vs_baseline.inference == "combined")]
    for r in cells.to_dict("records"):
        sampled = [r[f"sampled {c}"] for c in ("difference", "ci_low", "ci_high")]
        deterministic = [r[f"deterministic {c}"] for c in ("difference", "ci_low", "ci_high")]
        if np.isnan(sampled[0]):
            continue
        margin = design.reward_margin * abs(r["sampled baseline"])
        n_seeds = int(r["n_seeds"])
        verdict = decide(sampled[1], sampled[2], -margin, n_seeds)
        played = (f"deterministic {deterministic[0]:+.0f} [{deterministic[1]:+.0f}, {deterministic[2]:+.0f}]"
                  if np.isfinite(deterministic[0]) else "deterministic not played (sampled only)")
        loss = (f"; a significant loss ({-sampled[0] / abs(r['sampled baseline']):.0%} of the baseline's reward: the "
                "interval lies below 0) that the interval cannot place beyond the margin"
                if verdict != FAILS and n_seeds >= 2 and sampled[2] < 0 else "")
        rows.append(_row("masksembles_reward", r["env"], verdict,
                         f"Masksembles - baseline, sampled {sampled[0]:+.0f} [{sampled[1]:+.0f}, {sampled[2]:+.0f}] "
                         f"against the margin {-margin:+.0f} ({design.reward_margin:.0%} of the baseline's "
                         f"{r['sampled baseline']:.0f}){loss}; {played}; {n_seeds} seed(s)", n_seeds, design))
    return rows


def _require_family_intervals(table: pd.DataFrame, name: str) -> None:
    """One clear error for a table written before it carried its simultaneous intervals."""
    missing = sorted({"family_size", "family_ci_low", "family_ci_high"} - set(table.columns))
    if missing:
        raise ValueError(f"the claims need tables/{name} with {missing}, which older code did not write; rebuild "
                         "it first: `make reproduce` runs notebook 3 before notebook 6.")


def ood_conditions(metrics: pd.DataFrame | None, env: str, ood_set: str = "perturbed") -> int | None:
    """The fewest distinct OOD conditions (clusters) of any run of `env` in `ood_set` (ood_metrics' n_ood_clusters,
    a mean over the cell's seeds, so its minimum over cells); None where the table does not say."""
    if metrics is None or "n_ood_clusters" not in metrics.columns:
        return None
    rows = metrics[(metrics["env"] == env) & (metrics["ood_set"] == ood_set)]
    return int(np.floor(rows["n_ood_clusters"].min())) if not rows.empty else None


def _untestable(metrics: pd.DataFrame | None, env: str, design: ClaimDesign) -> str | None:
    found = ood_conditions(metrics, env)
    return not_testable(found, design.min_ood_conditions) if found is not None and found < design.min_ood_conditions \
        else None


def auroc_claim(pairwise: pd.DataFrame, design: ClaimDesign = ClaimDesign(),
                metrics: pd.DataFrame | None = None) -> list[dict[str, str]]:
    """Per env, perturbed states: Masksembles and Ensemble each above MC Dropout and MC DropConnect.

    For value_std and policy_std separately, on the per-seed AUROC differences of the four pairs
    (`paper_tables.auroc_between_methods`): a measure holds when all four intervals lie above 0 (all must, so
    each pair's own 95% interval), does not hold when some pair's simultaneous interval over the four lies below 0
    (one of four chances: Bonferroni, the same 5% risk as the other way); the two measures combine with `combine`.
    An env whose OOD states have too few distinct conditions (`metrics`' n_ood_clusters) is not testable.
    """
    _require_family_intervals(pairwise, "auroc_between_methods")
    rows = []
    perturbed = pairwise[pairwise.ood_set == "perturbed"]
    for env_id in pd.unique(perturbed.env):
        verdicts, parts, seeds = [], [], []
        for measure in SPREAD_MEASURES:
            cells = perturbed[(perturbed.env == env_id) & (perturbed.measure == measure)]
            cells = cells.set_index(["method", "versus"]).reindex(AUROC_ORDER_PAIRS).dropna(subset=["difference"])
            if len(cells) < len(AUROC_ORDER_PAIRS):
                continue
            n_seeds = int(cells.n_seeds.min())
            seeds.append(n_seeds)
            if n_seeds < 2:
                verdict = inconclusive(n_seeds)
            elif (cells.ci_low > 0).all():
                verdict = HOLDS
            elif (cells.family_ci_high < 0).any():
                verdict = FAILS
            else:
                verdict = inconclusive(n_seeds)
            verdicts.append(verdict)
            parts.append(f"{measure} ({verdict}): " + ", ".join(
                f"{a} - {b} {r.difference:+.2f} [{r.ci_low:+.2f}, {r.ci_high:+.2f}]"
                for (a, b), r in cells.iterrows()))
        n = min(seeds, default=0)
        verdict = _untestable(metrics, env_id, design) or combine(verdicts, n)
        rows.append(_row("auroc_order", env_id, verdict,
                         "; ".join(parts) + (f"; {n} seed(s); {_states_note(pairwise)}" if seeds else "") if parts
                         else "needs a run of each method", n, design))
    return rows


def _states_note(pairwise: pd.DataFrame) -> str:
    """Which states the AUROC order compared: the registered common set, or (until it is scored) each method's own."""
    if "states" in pairwise.columns and set(pairwise["states"]) == {"common"}:
        return "on one common state set per (env, seed): the baseline's, scored by every method (paired)"
    return ("on each method's own states (the registered common-state comparison is not scored yet: "
            "docs/preregistration.md)")


def _t_bounds(values: np.ndarray, level: float) -> tuple[float, float]:
    """Student's t interval of the mean of per-seed values (NaN with fewer than 2)."""
    if values.size < 2:
        return np.nan, np.nan
    half = student_t.ppf(0.5 + level / 2.0, values.size - 1) * values.std(ddof=1) / np.sqrt(values.size)
    return float(values.mean() - half), float(values.mean() + half)


def levitation_claim(spawn: pd.DataFrame | None, design: ClaimDesign = ClaimDesign()) -> list[dict[str, str]]:
    """Ant: value uncertainty higher in the first steps than later *and* higher in the air than on the floor.

    Per member method, over its seeds (`results/<profile>/spawn/summary.csv`, one row per run): log(value-std
    spawn ratio) and airborne AUROC - 0.5, each with a t interval simultaneous over the claim's 2 x methods
    intervals (Bonferroni: a verdict reached by "some 3 of 4" or "some 2 of 4" must not ride on many chances). A
    method flags the spawn when both lie above 0 and does not when either lies below 0. The claim holds when more
    than half of the methods flag it, does not hold when so many do not that no majority is left.
    """
    ant = spawn[spawn.env == "Ant-v5"] if spawn is not None else pd.DataFrame()
    if ant.empty:
        return [_row("levitation", "Ant-v5", UNTESTED, "no Ant member-method run yet (notebook 12)", 0, design)]
    if "seed" not in ant.columns:
        raise ValueError("the levitation claim reads one row per run (results/<profile>/spawn/summary.csv, with a "
                         "seed column), not the seed means of tables/spawn_uncertainty.")
    methods = [m for m in SPAWN_METHODS if m in set(ant.method)]
    level = 1.0 - (1.0 - design.level) / (2 * len(methods))
    flags, parts = [], []
    n_seeds = int(ant.groupby("method").seed.nunique().min())
    for method in methods:
        rows = ant[ant.method == method]
        ratio = _t_bounds(np.log(rows.value_std_spawn_ratio.to_numpy(float)), level)
        air = _t_bounds(rows.value_std_airborne_auroc.to_numpy(float) - 0.5, level)
        each = [decide(*ratio, 0.0, len(rows)), decide(*air, 0.0, len(rows))]
        flags.append(HOLDS if all(v == HOLDS for v in each) else FAILS if FAILS in each else inconclusive(len(rows)))
        parts.append(f"{method}: spawn/later {rows.value_std_spawn_ratio.mean():.2f} (log [{ratio[0]:+.2f}, "
                     f"{ratio[1]:+.2f}]), air AUROC {rows.value_std_airborne_auroc.mean():.2f} (-0.5 [{air[0]:+.2f}, "
                     f"{air[1]:+.2f}]): {flags[-1]}")
    majority = len(methods) // 2 + 1
    verdict = (inconclusive(n_seeds) if n_seeds < 2 else HOLDS if flags.count(HOLDS) >= majority
               else FAILS if flags.count(FAILS) > len(methods) - majority else inconclusive(n_seeds))
    return [_row("levitation", "Ant-v5", verdict, "; ".join(parts) + f"; intervals simultaneous over "
                 f"{2 * len(methods)}; {n_seeds} seed(s) (notebook 12)", n_seeds, design)]


def spearman_interval(x: np.ndarray, y: np.ndarray, rng: np.random.Generator, n_boot: int = 2000,
                      level: float = LEVEL) -> tuple[float, float, float]:
    """(rho, low, high): Spearman's rho over cells, its interval the wider of a bootstrap over the cells and the
    Fisher-z interval with Bonett and Wright's (2000) standard error sqrt((1 + rho^2 / 2) / (n - 3))."""
    n = x.size
    rank = lambda v: pd.Series(v).rank().to_numpy()  # noqa: E731
    rho = float(np.corrcoef(rank(x), rank(y))[0, 1])
    draws = rng.integers(0, n, size=(int(n_boot), n))
    boot = np.array([np.corrcoef(rank(x[d]), rank(y[d]))[0, 1] for d in draws])
    low, high = np.nanquantile(boot, [(1 - level) / 2, (1 + level) / 2])
    z, se = np.arctanh(np.clip(rho, -0.999999, 0.999999)), np.sqrt((1 + rho ** 2 / 2) / (n - 3))
    q = norm.ppf(0.5 + level / 2)
    return rho, float(min(low, np.tanh(z - q * se))), float(max(high, np.tanh(z + q * se)))


def js_claim(metrics: pd.DataFrame, design: ClaimDesign = ClaimDesign(), n_boot: int = 2000) -> list[dict[str, str]]:
    """Per env family (MuJoCo, Atari: their scales and seed counts differ), perturbed states: Spearman's rho of
    policy_js and policy_std AUROCs over the (env, method) cells (means over seeds), with `spearman_interval`.

    Holds when the interval lies at or above the threshold, does not hold when it lies below; needs 4 cells.
    Envs whose OOD states are not testable are left out.
    """
    from paper_lib.agents.envs import is_atari

    perturbed = metrics[metrics.ood_set == "perturbed"]
    wide = perturbed.pivot_table(index=["env", "method"], columns="measure", values="auroc", aggfunc="mean")
    if not {"policy_js", "policy_std"} <= set(wide.columns):
        return [_row("js_like_std", "all", UNTESTED, "no member-method scores yet", 0, design)]
    pairs = wide[["policy_js", "policy_std"]].dropna()
    rows = []
    for family in ("MuJoCo", "Atari"):
        envs = [e for e in pd.unique(pairs.index.get_level_values("env")) if ("Atari" if is_atari(e) else "MuJoCo")
                == family]
        left_out = [e for e in envs if _untestable(metrics, e, design)]
        cells = pairs[pairs.index.get_level_values("env").isin([e for e in envs if e not in left_out])]
        if not envs:
            continue
        if len(cells) < 4:
            rows.append(_row("js_like_std", family, UNTESTED, f"{len(cells)} (env, method) cell(s); needs 4", 0, design))
            continue
        counts = perturbed[perturbed.env.isin(cells.index.get_level_values("env"))
                           & perturbed.measure.isin(["policy_js", "policy_std"])]
        n_seeds = int(counts.n_seeds.min()) if "n_seeds" in counts.columns else 1
        rho, low, high = spearman_interval(cells.policy_js.to_numpy(), cells.policy_std.to_numpy(),
                                           cell_rng(0, "js_like_std", family), n_boot, design.level)
        verdict = decide(low, high, design.js_threshold, max(n_seeds, 2))
        gap = (cells.policy_js - cells.policy_std).abs()
        rows.append(_row("js_like_std", family, verdict,
                         f"Spearman rho {rho:.2f} [{low:.2f}, {high:.2f}] over {len(cells)} (env, method) cells "
                         f"against {design.js_threshold}; |AUROC difference| median {gap.median():.3f}, max "
                         f"{gap.max():.3f}" + (f"; left out (too few OOD conditions): {', '.join(left_out)}"
                                               if left_out else "") + f"; {n_seeds} seed(s) per cell", n_seeds,
                         design))
    return rows


def detector_claim(versus: pd.DataFrame, design: ClaimDesign = ClaimDesign(),
                   metrics: pd.DataFrame | None = None, claim: str = "members_vs_detectors",
                   ood_set: str = "perturbed") -> list[dict[str, str]]:
    """Per env, perturbed states: does some member measure beat its runs' best member-free detector? (Claim 7 reads
    the same rule on PEDM's protocol: `claim="members_vs_pedm"`, `pedm_claim.pedm_versus`.)

    Success is at least one (method, measure) cell above the detector, failure every cell below it, each at
    the same 5% risk of a wrong verdict: holds when some cell's simultaneous interval (Bonferroni over the env's
    m cells, `paper_tables.auroc_vs_detectors`) lies above 0, since any one of m 95% intervals would clear 0 by
    chance far more often than 5%; does not hold when every cell's own 95% interval lies below 0 (all m must,
    so no correction is needed); inconclusive otherwise. Cells of one seed count for neither. An env whose OOD
    states have too few distinct conditions is not testable (a detector at AUROC 1 on 3 mazes is no comparison).
    """
    _require_family_intervals(versus, "auroc_vs_detectors")
    rows = []
    for env_id, cells in versus[versus.ood_set == ood_set].groupby("env", sort=False):
        above, below = int((cells.ci_low > 0).sum()), int((cells.ci_high < 0).sum())
        tested = cells[cells.n_seeds >= 2]
        n_seeds = int(cells.n_seeds.min())
        if tested.empty:
            verdict = inconclusive(n_seeds)
        elif (tested.family_ci_low > 0).any():
            verdict = HOLDS
        elif len(tested) == len(cells) and (tested.ci_high < 0).all():
            verdict = FAILS
        else:
            verdict = inconclusive(n_seeds)
        label, shown = _shown_cell(cells, tested, verdict)
        digits = 3 if verdict == HOLDS else 2  # a deciding bound of +0.005 must not print as +0.00
        rows.append(_row(claim, env_id, _untestable(metrics, env_id, design) or verdict,
                         f"of {len(cells)} measure cells (95% intervals): {above} above the detector, "
                         f"{len(cells) - above - below} tied, {below} below; {label} {shown.method} {shown.measure} "
                         f"({_seeds(int(shown.n_seeds))}) {shown.difference:+.{digits}f} "
                         f"{_bounds(shown.ci_low, shown.ci_high, digits)}, simultaneous over {int(shown.family_size)} "
                         f"{_bounds(shown.family_ci_low, shown.family_ci_high, digits)} vs {shown.detector}; "
                         f"{n_seeds} seed(s)", n_seeds, design))
    return rows


def _shown_cell(cells: pd.DataFrame, tested: pd.DataFrame, verdict: str) -> tuple[str, pd.Series]:
    """The cell the evidence names: when the claim holds, the one that decides it (its simultaneous interval
    lies highest above 0), so a reader never sees "holds" beside an interval that contains 0; otherwise the
    cell with the largest difference."""
    if verdict == HOLDS:
        return "deciding cell", tested.loc[tested.family_ci_low.idxmax()]
    return "best", cells.loc[cells.difference.idxmax()]


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _bounds(low: float, high: float, digits: int = 2) -> str:
    """An interval as the evidence prints it; a cell of one seed has none (Student's t needs two)."""
    return "[no interval: 1 seed]" if np.isnan(low) or np.isnan(high) else f"[{low:+.{digits}f}, {high:+.{digits}f}]"


def speed_rows(timings: pd.DataFrame | None, design: ClaimDesign = ClaimDesign()) -> list[dict[str, str]]:
    """The paper's speed claim per benchmark env (`speed_claim`: Masksembles / MC Dropout over the benchmark's
    repetitions); no seeds, so no seed plan: its verdicts are not staged."""
    from paper_lib.reporting.speed_claim import speed_claim

    return [{"claim": CLAIMS["speed"], "env": env, "verdict": verdict, "evidence": evidence}
            for env, verdict, evidence in speed_claim(timings, design.speed_inference, design.speed_training,
                                                      design.speed_margin, design.speed_min_repetitions,
                                                      design.level)]


def base_verdict(verdict: str) -> str:
    """A staged verdict's reading without its seed plan: holds, does not hold, mixed, inconclusive, undecidable,
    not testable (for colouring and counting)."""
    verdict = re.sub(r", provisional \(.*\)$", "", verdict)
    for word in ("inconclusive", "undecidable", "not testable"):
        if verdict.startswith(word):
            return word
    return verdict


def paper_claims(vs_baseline: pd.DataFrame, pairwise: pd.DataFrame, metrics: pd.DataFrame, versus: pd.DataFrame,
                 spawn: pd.DataFrame | None, design: ClaimDesign = ClaimDesign(),
                 timings: pd.DataFrame | None = None, pedm_aurocs: pd.DataFrame | None = None) -> pd.DataFrame:
    """Every claim's rows, in the order of ``CLAIMS``; `timings`: the benchmark's repetitions
    (`speed_claim.read_timings`), None while none is committed; `pedm_aurocs`: the runs' PEDM-protocol AUROCs
    (`pedm_claim.RUN_AUROC_COLUMNS`), None while no run has them."""
    from paper_lib.reporting.pedm_claim import pedm_rows

    rows = (reward_claim(vs_baseline, design) + auroc_claim(pairwise, design, metrics)
            + levitation_claim(spawn, design) + js_claim(metrics, design) + speed_rows(timings, design)
            + detector_claim(versus, design, metrics) + pedm_rows(pedm_aurocs, design, list(metrics["env"].unique())))
    return pd.DataFrame(rows, columns=COLUMNS)
