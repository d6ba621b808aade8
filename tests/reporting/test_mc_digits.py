"""Issue 36, item 6: an AUROC cell prints only the digits its Monte Carlo (scoring seed) noise supports."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from paper_lib.reporting import tables


def _cells(scoring_std: list[float], n_scoring_seeds: list[int], n_seeds: list[int]) -> pd.DataFrame:
    """Pooled rows as `summarize_seeds` gives them: AUROC, its 95% CI, seeds and spread over scoring seeds."""
    n = len(scoring_std)
    return pd.DataFrame({"method": [f"m{i}" for i in range(n)], "n_seeds": n_seeds, "auroc": np.full(n, 0.41234),
                         "auroc_ci_low": np.full(n, 0.38765), "auroc_ci_high": np.full(n, 0.44321),
                         "auroc_scoring_std": scoring_std, "n_scoring_seeds": n_scoring_seeds})


def test_the_mc_standard_error_of_a_cell_is_its_scoring_spread_over_sqrt_of_scoring_and_training_seeds():
    # population std s over m scoring seeds: the run's SE is s / sqrt(m - 1); a cell of n runs divides by sqrt(n)
    df = _cells([0.012, 0.012, 0.0, 0.01], [5, 5, 1, 1], [1, 4, 3, 1])
    se = tables.mc_standard_error(df, "auroc")
    assert se.tolist()[:3] == pytest.approx([0.006, 0.003, 0.0])
    assert np.isnan(se.iloc[3])  # one scoring seed of a stochastic method: its MC noise is unknown
    assert tables.mc_standard_error(df.drop(columns="auroc_scoring_std"), "auroc") is None  # no MC spread: no rule


def test_a_cell_with_mc_standard_error_0006_prints_two_decimals_and_0004_three():
    df = _cells([0.012, 0.008, 0.0], [5, 5, 1], [1, 1, 3]).assign(se=[0.006, 0.004, 0.0])
    cells = tables.interval_cells(df, "auroc", "auroc_ci_low", "auroc_ci_high", mc_se="se")
    assert cells.tolist() == ["0.41 [0.39, 0.44]\u00b9", "0.412 [0.388, 0.443]\u00b9", "0.412 [0.388, 0.443]"]
    assert tables.mc_decimals(pd.Series([0.006, 0.004, 0.06, np.nan])).tolist() == [2, 3, 1, 3]


def test_save_table_drops_the_decimal_the_mc_noise_does_not_support_and_says_why(tmp_path):
    # SE 0.012 / sqrt(4) = 0.006 -> 2 decimals; 0.008 / sqrt(4) = 0.004 -> 3; deterministic (one scoring seed) -> 3;
    # 0.012 / sqrt(4 * 4) = 0.003 over four training seeds -> 3
    df = _cells([0.012, 0.008, 0.0, 0.012], [5, 5, 1, 5], [1, 1, 3, 4])
    paths = tables.save_table(df, tmp_path / "t", caption="AUROC.",
                              intervals={"auroc": ("auroc_ci_low", "auroc_ci_high")})
    md = paths["md"].read_text()
    rows = {line.split("|")[1].strip(): line for line in md.splitlines()[4:]}
    assert "0.41 [0.39, 0.44]" in rows["m0"] and "0.412 [0.388, 0.443]" in rows["m1"]
    assert "0.412 [0.388, 0.443]" in rows["m2"] and "0.412 [0.388, 0.443]" in rows["m3"]
    assert md.splitlines()[0].endswith(f"{tables.MC_DIGITS_NOTE}.")  # the caption says why
    assert pd.read_csv(paths["csv"])["auroc"].tolist() == pytest.approx([0.41234] * 4)  # the CSV keeps every digit
    supported = tables.save_table(df.iloc[1:], tmp_path / "s", caption="AUROC.",
                                  intervals={"auroc": ("auroc_ci_low", "auroc_ci_high")})
    assert tables.MC_DIGITS_NOTE not in supported["md"].read_text()  # no cell shortened: no note


# ------------------------------------------------------------------------------------------------- differences
def test_mc_standard_error_of_a_mean_over_runs():
    from paper_lib.scoring.statistics import difference_mc_standard_error, mc_standard_error

    # two runs of 5 scoring seeds, population stds 0.01 and 0.02: errors 0.005 and 0.01, their mean's sqrt(sum sq)/2
    assert mc_standard_error([0.01, 0.02], [5, 5]) == pytest.approx(np.hypot(0.005, 0.01) / 2)
    assert mc_standard_error([0.0, 0.0], [1, 1]) == 0.0  # deterministic: no MC noise
    assert np.isnan(mc_standard_error([0.01], [1]))  # one draw of a stochastic method: unknown
    assert difference_mc_standard_error(0.003, 0.004) == pytest.approx(0.005)


def _difference_inputs(scoring_std: float) -> tuple[pd.DataFrame, dict]:
    rows, reps = [], {}
    for method, base in (("masksembles", 0.7), ("mc_dropout", 0.6)):
        for seed in range(3):
            r = np.random.default_rng(seed).normal(base + 0.01 * seed, 0.01, 200)
            std = 0.0 if method == "masksembles" else scoring_std
            rows.append({"env": "E", "method": method, "seed": seed, "ood_set": "perturbed", "measure": "value_std",
                         "auroc": float(r.mean()), "auroc_scoring_std": std, "n_scoring_seeds": 1 if std == 0 else 5})
            reps[("E", method, seed, "perturbed", "value_std")] = r
    return pd.DataFrame(rows), reps


@pytest.mark.parametrize("scoring_std,decimals", [(0.03, 2), (0.01, 3)])
def test_a_difference_prints_the_digits_its_mc_noise_supports(tmp_path, scoring_std, decimals):
    """MC Dropout's runs with spread s over 5 scoring seeds: error s/2/sqrt(3) per cell; 0.0087 drops a decimal,
    0.0029 keeps three, in the difference's cell and in the MC side's own column."""
    from paper_lib.reporting.paper_tables import auroc_between_methods
    from paper_lib.reporting.tables import MC_DIGITS_NOTE, save_table

    metrics, reps = _difference_inputs(scoring_std)
    table = auroc_between_methods(metrics, reps, [("masksembles", "mc_dropout")], ("value_std",), n_boot=200)
    row = table.iloc[0]
    assert row.versus_auroc_mc_se == pytest.approx(scoring_std / 2 / np.sqrt(3))
    assert row.auroc_mc_se == 0.0 and row.difference_mc_se == pytest.approx(row.versus_auroc_mc_se)
    md = save_table(table, tmp_path / "t", "cap.", intervals={"difference": ("ci_low", "ci_high")})["md"].read_text()
    body = md.split("\n\n", 1)[1]
    assert "_mc_se" not in body  # the CSV keeps the errors, the shown table does not
    cells = body.splitlines()[2].split("|")
    header = [c.strip() for c in body.splitlines()[0].split("|")]
    difference = cells[header.index("difference [95% CI]")].strip()
    versus = cells[header.index("versus_auroc")].strip()
    assert len(difference.split(" ")[0].split(".")[1]) == decimals
    assert len(versus.split(".")[1]) == decimals
    assert (MC_DIGITS_NOTE in md) == (decimals == 2)
