"""Table 2's sequence-detector rows: numbers where a run's `sequence_score` stage has run, 'not scored' where not."""

import numpy as np
import pandas as pd

from paper_lib.reporting.paper_tables import NOT_APPLICABLE, NOT_SCORED, auroc_table, auroc_table_with_sequences
from paper_lib.reporting.tables import save_table

ATARI = "SeaquestNoFrameskip-v4"


def _metrics() -> pd.DataFrame:
    """Two seeds of baseline and Masksembles in HalfCheetah, one of each in Seaquest."""
    rows = [{"env": env, "method": method, "seed": seed, "measure": "knn_obs", "auroc": 0.5 + 0.1 * seed + 0.01 * i}
            for i, (env, method, seed) in enumerate([("HalfCheetah-v5", "baseline", 0), ("HalfCheetah-v5", "baseline", 1),
                                                     ("HalfCheetah-v5", "masksembles", 0),
                                                     ("HalfCheetah-v5", "masksembles", 1),
                                                     (ATARI, "baseline", 0), (ATARI, "masksembles", 0)])]
    return pd.DataFrame(rows)


def test_a_run_without_the_file_shows_not_scored_and_other_cells_are_unchanged(tmp_path):
    metrics = _metrics()
    # only HalfCheetah baseline seed 0 has been scored by the sequence detectors
    sequences = pd.DataFrame([{"env": "HalfCheetah-v5", "method": "baseline", "seed": 0, "measure": m, "auroc": a}
                              for m, a in (("episode_mean", 0.81), ("window_forest", 0.77))])
    methods = ["baseline", "masksembles"]
    table, text = auroc_table_with_sequences(metrics, sequences, methods, ("HalfCheetah-v5",))
    assert table[["method", "measure"]].values.tolist() == [
        ["baseline", "episode_mean"], ["baseline", "knn_obs"], ["baseline", "window_forest"],
        ["masksembles", "episode_mean"], ["masksembles", "knn_obs"], ["masksembles", "window_forest"]]
    plain = auroc_table(metrics, methods)
    pd.testing.assert_frame_equal(table[table.measure == "knn_obs"].reset_index(drop=True),
                                  plain.assign(method=plain["method"].astype(str)))  # existing cells as they were
    cell = table.set_index(["method", "measure"])
    note = text.set_index(table.set_index(["method", "measure"]).index)
    assert cell.loc[("baseline", "episode_mean"), "HalfCheetah-v5"] == 0.81  # the CSV keeps the number
    assert note.loc[("baseline", "episode_mean"), "HalfCheetah-v5"] == "0.81 (1 of 2 seeds)"
    assert np.isnan(cell.loc[("masksembles", "window_forest"), "HalfCheetah-v5"])
    assert note.loc[("masksembles", "window_forest"), "HalfCheetah-v5"] == NOT_SCORED
    assert note.loc[("masksembles", "window_forest"), ATARI] == NOT_APPLICABLE

    paths = save_table(table, tmp_path / "t", caption="Table 2", float_format="%.2f", cell_text=text)
    md = paths["md"].read_text()
    assert "| masksembles | window_forest | not scored | n/a |" in " ".join(md.split())
    assert "0.81 (1 of 2 seeds)" in md and "0.81 (1 of 2 seeds)" in paths["tex"].read_text()
    back = pd.read_csv(paths["csv"])
    assert back["HalfCheetah-v5"].dtype == float and back[ATARI].dtype == float  # numbers for code, NaN unscored


def test_no_sequence_file_at_all_still_gives_the_rows():
    table, text = auroc_table_with_sequences(_metrics(), pd.DataFrame(columns=["env", "method", "seed", "measure",
                                                                                "auroc"]),
                                             ["baseline", "masksembles"], ("HalfCheetah-v5",))
    rows = table.measure != "knn_obs"
    assert (text.loc[rows, "HalfCheetah-v5"] == NOT_SCORED).all() and table.loc[rows, "HalfCheetah-v5"].isna().all()


def test_pedm_row_is_not_applicable_where_its_envs_leave_the_env_out():
    """PEDM scores Table 2's states only where an observation determines the state: n/a elsewhere, per detector."""
    metrics = pd.concat([_metrics(), _metrics().query("env == 'HalfCheetah-v5'").assign(env="Walker2d-v5")])
    peers = pd.DataFrame([{"env": env, "method": "baseline", "seed": seed, "measure": m, "auroc": 0.9}
                          for env in ("HalfCheetah-v5", "Walker2d-v5") for seed in (0, 1)
                          for m in ("episode_mean", "window_forest", "pedm") if not (m == "pedm" and env != "HalfCheetah-v5")])
    envs = {"episode_mean": ("HalfCheetah-v5", "Walker2d-v5"), "window_forest": ("HalfCheetah-v5", "Walker2d-v5"),
            "pedm": ("HalfCheetah-v5",)}
    table, text = auroc_table_with_sequences(metrics, peers, ["baseline", "masksembles"], envs,
                                             rows=("episode_mean", "window_forest", "pedm"))
    cell, note = table.set_index(["method", "measure"]), text.set_index(table.set_index(["method", "measure"]).index)
    assert cell.loc[("baseline", "pedm"), "HalfCheetah-v5"] == 0.9 and note.loc[("baseline", "pedm"), "HalfCheetah-v5"] == ""
    assert note.loc[("baseline", "pedm"), "Walker2d-v5"] == NOT_APPLICABLE  # scored by the sequence rows, not PEDM
    assert cell.loc[("baseline", "episode_mean"), "Walker2d-v5"] == 0.9
    assert note.loc[("masksembles", "pedm"), "HalfCheetah-v5"] == NOT_SCORED
    assert note.loc[("masksembles", "pedm"), ATARI] == NOT_APPLICABLE
