"""Per-run rows computed once and kept while the run's inputs stay (`experiments.kept_rows`): spawn's rollouts and
value_level's rows move across CPUs, so a landing must not compute the committed runs again."""

from __future__ import annotations

import pandas as pd

from paper_lib.experiments import spawn, value_level
from paper_lib.experiments.kept_rows import RECORD, fingerprint, kept_rows

RUNS = [("Ant-v5", "masksembles", 0), ("Ant-v5", "masksembles", 1)]


def _tables(folder) -> None:
    rows = pd.DataFrame({"env": "Ant-v5", "method": "masksembles", "seed": [0, 0, 1], "step": [0, 1, 0],
                         "value_std": [3.0, 1.0, 2.0]})
    rows.to_csv(folder / "rollouts.csv", index=False)
    rows.groupby(["env", "method", "seed"], as_index=False)["value_std"].mean().to_csv(folder / "summary.csv",
                                                                                        index=False)


def test_a_landed_run_keeps_its_rows_and_a_new_or_changed_one_is_computed(tmp_path):
    _tables(tmp_path)
    first = kept_rows(tmp_path, ("rollouts", "summary"), {RUNS[0]: "a", RUNS[1]: "b"})  # no record yet: all kept
    assert all(first.has(run) for run in RUNS)
    assert first.tables["rollouts"][RUNS[0]]["value_std"].tolist() == [3.0, 1.0]
    assert first.tables["summary"][RUNS[1]]["value_std"].tolist() == [2.0]
    first.record.to_csv(tmp_path / RECORD, index=False)
    new = ("Ant-v5", "masksembles", 2)
    later = kept_rows(tmp_path, ("rollouts", "summary"), {RUNS[0]: "a", RUNS[1]: "c", new: "d"})  # seed 1 retrained
    assert later.has(RUNS[0]) and not later.has(RUNS[1]) and not later.has(new)
    assert later.record["fingerprint"].tolist() == ["a", "c", "d"]
    (tmp_path / "summary.csv").write_text("env,method,seed,value_std\n")  # a run kept only where every table has it
    assert not kept_rows(tmp_path, ("rollouts", "summary"), {RUNS[0]: "a"}).has(RUNS[0])
    assert not kept_rows(tmp_path / "elsewhere", ("rollouts",), {RUNS[0]: "a"}).has(RUNS[0])


def test_fingerprints_follow_the_files_and_the_settings(tmp_path):
    model, data = tmp_path / "model.zip", tmp_path / "seed0.npz"
    model.write_bytes(b"weights")
    data.write_bytes(b"states")
    base = spawn.run_fingerprint(tmp_path, 5, 100, 10)
    assert base == spawn.run_fingerprint(tmp_path, 5, 100, 10) and base != spawn.run_fingerprint(tmp_path, 5, 50, 10)
    level = value_level.run_fingerprint(tmp_path, data, 5)
    data.write_bytes(b"other states")
    assert value_level.run_fingerprint(tmp_path, data, 5) != level  # a recollected dataset is computed again
    model.write_bytes(b"retrained")
    assert spawn.run_fingerprint(tmp_path, 5, 100, 10) != base
    assert fingerprint([tmp_path / "absent"], {}) != fingerprint([model], {})
