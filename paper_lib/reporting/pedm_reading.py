"""Notebook 14's prose, computed: where our run of PEDM's protocol differs from PEDM's, and what its table says.

Every number in these lines comes from the runs' metrics, their provenance (the settings each `pedm` stage ran
with) or the code that sets the protocol (`ood.pedm_protocol`, `measures.dynamics.PEDMConfig`), never typed in, so
the notebook's words follow the data when runs are added or settings change.
"""

from __future__ import annotations

import pandas as pd

from paper_lib.measures.definitions import ALL_MEMBER_MEASURES
from paper_lib.reporting.pedm_table import MEAN_KIND, PEDM_TEST_EPISODES, SEVERITY_ORDER, scorer_order
from paper_lib.scoring.pedm_scores import CLOCK

#: How each of PEDM's kinds reads in prose, with the unit of its value.
KIND_WORDS = {"bm_factor": "body mass x{}", "act_factor": "action x{}", "act_offset": "action offset +{}",
              "act_noise": "action noise std {}", "force_vector": "force {} N on a foot along x"}
VERSUS = "pedm"
#: The least share of injected episodes a scorer must flag for its delay to be named the shortest: a delay resting on
#: a few episodes says little.
MIN_DETECTED = 0.5


def _values(values: list) -> str:
    return " / ".join(str(v) for v in values)


def protocol_differences(settings: dict[str, list], envs: list[str], methods: list[str]) -> list[str]:
    """Where the protocol as run here differs from PEDM's (Haider et al., AAMAS 2023), one line per difference:
    `settings` as `pedm_table.protocol_settings` gives them, `envs` and `methods` those with runs."""
    from paper_lib.measures.dynamics import PEDMConfig
    from paper_lib.ood.pedm_protocol import FOOT, HALF_CHEETAH_VALUES, PEDM_CHEETAH_MASS

    cheetah = "; ".join(KIND_WORDS[kind].format(" / ".join(f"{v:g}" for v in values))
                        for kind, values in HALF_CHEETAH_VALUES.items())
    others = [env for env in envs if env != "HalfCheetah-v5"]
    lines = [
        f"**Envs:** gymnasium's MuJoCo v5 envs ({', '.join(envs)}), not PEDM's HalfCheetah on the old gym API and "
        "mujoco-py (its code runs on neither gymnasium nor the `mujoco` bindings).",
        f"**Agents:** our PPO agents ({', '.join(methods)}), acting deterministically (the mean action), not "
        "PEDM's TD3; each run fits its own PEDM on its own agent's ID transitions.",
        f"**Perturbations:** PEDM's HalfCheetah values, minor / severe ({cheetah})"
        + (f"; on {', '.join(others)} the mass and action values are kept and the force is the same share of the "
           f"robot's mass (value x mass / {PEDM_CHEETAH_MASS:g} kg, PEDM's cheetah) on "
           + ", ".join(f"{env}'s `{FOOT[env]}`" for env in others)
           + " (docs/ood_benchmark.md gives the newtons)" if others else "") + ".",
    ]
    if settings:
        lines += [
            f"**PEDM's training:** {_values(settings.get('epochs', []))} epochs, not PEDM's {PEDMConfig().epochs} "
            "(docs/deviations.md: the cut, chosen from PEDM's validation curve on one run, and what it costs).",
            f"**Episodes:** {_values(settings.get('test_episodes', []))} test episodes per kind and severity, not "
            f"PEDM's {PEDM_TEST_EPISODES}; each run's PEDM fits on PEDM's number of ID episodes "
            f"({_values(settings.get('id_episodes', []))}), and {_values(settings.get('threshold_episodes', []))} "
            "more held-out ID episodes set each scorer's detection-delay threshold, calibrated on whole episodes "
            "(PEDM reports no delay).",
        ]
    return lines


def _run_means(runs: pd.DataFrame) -> pd.DataFrame:
    """Per (env, severity, scorer): the mean over the env's runs (every method and seed) of the per-severity mean
    AUROC and time-matched AUROC, and how many runs it rests on."""
    means = runs[runs["kind"] == MEAN_KIND]
    return (means.groupby(["env", "severity", "scorer"], sort=False)
            .agg(auroc=("auroc", "mean"), n_runs=("auroc", "count"), matched=("auroc_time_matched", "mean"))
            .reset_index())


def _delays(runs: pd.DataFrame) -> pd.DataFrame:
    """Per (env, severity, scorer): the median over the env's runs and kinds of each run's median delay (steps from
    the injection to the first flag, in the episodes the scorer flagged), and the mean share of episodes flagged."""
    kinds = runs[runs["kind"] != MEAN_KIND]
    return (kinds.groupby(["env", "severity", "scorer"], sort=False)
            .agg(delay=("delay_median", "median"), detected=("detected", "mean")).reset_index())


def _delay_words(delays: pd.DataFrame) -> str | None:
    """"median delay of PEDM 7.5 steps (100% of episodes flagged), the shortest episode_mean's 5 steps (85% ...)": per
    scorer (the index), its median delay and mean share of episodes flagged over the kinds, as `_delays` gives them.
    The shortest is named among the scorers that flag at least MIN_DETECTED of the injected episodes."""
    delays = delays.dropna(subset=["delay"])
    if delays.empty:
        return None

    def said(scorer: str) -> str:
        return f"{delays.at[scorer, 'delay']:g} steps ({delays.at[scorer, 'detected']:.0%} of episodes flagged)"

    pedm = f"median delay of PEDM {said(VERSUS)}" if VERSUS in delays.index else None
    enough = delays[delays["detected"] >= MIN_DETECTED]
    if enough.empty:
        return "; ".join(filter(None, [pedm, f"no scorer flags {MIN_DETECTED:.0%} of the injected episodes"]))
    fastest = enough["delay"].idxmin()
    if pedm is not None and fastest != VERSUS:
        return f"{pedm}, the shortest {fastest}'s {said(fastest)}"
    return f"median delay {said(fastest)}, the shortest, by {fastest}"


def _clock_words(cell: pd.DataFrame) -> str | None:
    """"the clock (step index alone) 0.81, above it: pedm; time-matched AUROC best pedm 0.92": which scorers beat
    knowing only the time, and the best AUROC against the ID steps at the same step index (the clock's is 0.5).
    `cell` is `_run_means` of one env and severity, indexed by scorer."""
    if CLOCK not in cell.index:
        return None
    clock = cell.at[CLOCK, "auroc"]
    others = cell.drop(index=CLOCK)
    above = [s for s in others.index if others.at[s, "auroc"] > clock]
    words = f"the clock (step index alone) {clock:.2f}, " + (f"above it: {', '.join(above)}" if above else
                                                            "no scorer above it")
    matched = others["matched"].dropna()
    if not matched.empty:
        top = matched.idxmax()
        words += f"; time-matched AUROC best {top} {matched[top]:.2f}"
        if VERSUS in matched.index and top != VERSUS:
            words += f", PEDM {matched[VERSUS]:.2f}"
    return words


def protocol_reading(runs: pd.DataFrame) -> list[str]:
    """What the table and figures say, per env and severity: the best scorer, PEDM, the best of the agent's own
    measures, the scorers above the clock and their time-matched AUROC, and the detection delays; one line each, every
    number computed from `runs` (`pedm_table`'s long form). The clock is a reference, never "the best"."""
    if runs.empty:
        return ["No run has played PEDM's protocol yet: nothing to read."]
    means, delays = _run_means(runs), _delays(runs)
    lines = []
    for env in pd.unique(means["env"]):
        n_runs = runs[runs["env"] == env].drop_duplicates(["method", "seed"]).shape[0]
        hint = " (one run: a hint, not a finding)" if n_runs == 1 else ""
        for severity in [s for s in SEVERITY_ORDER if s in set(means["severity"])]:
            cell = means[(means["env"] == env) & (means["severity"] == severity)].set_index("scorer")
            if cell.empty:
                continue
            cell = cell.loc[scorer_order(list(cell.index))]
            scorers = cell.drop(index=CLOCK, errors="ignore")
            if scorers.empty:
                continue
            best = scorers["auroc"].idxmax()
            parts = [f"best **{best}** {cell.at[best, 'auroc']:.2f}"]
            if VERSUS in cell.index and best != VERSUS:
                parts.append(f"PEDM {cell.at[VERSUS, 'auroc']:.2f}")
            own = cell[cell.index.isin(ALL_MEMBER_MEASURES)]
            if not own.empty:
                top = own["auroc"].idxmax()
                parts.append(f"best agent measure {top} {own.at[top, 'auroc']:.2f} (over {int(own.at[top, 'n_runs'])} "
                             "member runs)")
            else:
                parts.append("no agent measure (no member run yet)")
            clock = _clock_words(cell)
            if clock is not None:
                parts.append(clock)
            words = _delay_words(delays[(delays["env"] == env) & (delays["severity"] == severity)].set_index("scorer"))
            if words is not None:
                parts.append(words)
            lines.append(f"{env}, {severity} kinds, mean AUROC over {n_runs} run(s){hint}: " + "; ".join(parts) + ".")
    return lines
