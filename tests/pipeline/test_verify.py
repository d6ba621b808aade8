"""File comparison behind `python -m paper_lib.pipeline.verify` (the whole command runs in
tests/pipeline/test_pipeline.py)."""

from __future__ import annotations

import numpy as np
import pytest

from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.verify import compare_files, runs_to_verify


def _pair(tmp_path, committed: str, fresh: str, suffix: str = ".csv"):
    a, b = tmp_path / f"committed{suffix}", tmp_path / f"fresh{suffix}"
    a.write_text(committed)
    b.write_text(fresh)
    return a, b


def test_identical_bytes_and_same_values_written_otherwise(tmp_path):
    assert compare_files(*_pair(tmp_path, "x,y\n1,0.5\n", "x,y\n1,0.5\n")).result == "identical"
    assert compare_files(*_pair(tmp_path, "x,y\n1,0.5\n", "x,y\n1,0.50\n")).result == "same values"


def test_the_largest_numeric_difference_and_its_column(tmp_path):
    found = compare_files(*_pair(tmp_path, "m,auroc,tpr\na,0.9,0.1\nb,0.8,nan\n", "m,auroc,tpr\na,0.9000001,0.1\nb,0.75,nan\n"))
    assert found.result == "numbers differ" and found.column == "auroc"
    assert found.max_abs_diff == pytest.approx(0.05)


@pytest.mark.parametrize("fresh, why", [("m,auroc\na,0.9\nb,0.8\n", "shape"), ("m,AUROC\na,0.9\n", "columns"),
                                        ("m,auroc\nc,0.9\n", "row 0"), ("m,auroc\na,nan\n", "NaN")])
def test_another_table_differs(tmp_path, fresh, why):
    found = compare_files(*_pair(tmp_path, "m,auroc\na,0.9\n", fresh))
    assert found.result == "differs" and why in found.note


def test_arrays_and_missing_files(tmp_path):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, np.array([[0.5, np.nan]], np.float32))
    np.save(b, np.array([[0.5 + 2 ** -20, np.nan]], np.float32))
    found = compare_files(a, b)
    assert found.result == "within tolerance" and found.max_abs_diff == pytest.approx(2 ** -20)  # float32 noise
    assert compare_files(a, tmp_path / "absent.npy").result == "missing"


def test_a_run_without_committed_results_is_refused_with_the_runs_that_have_them(tmp_path):
    cfg = load_run_config()
    with pytest.raises(ValueError, match="Nope-v5 baseline seed 0 has no committed checkpoint \\+ dataset \\+ scores"):
        runs_to_verify(cfg, ("score",), [("Nope-v5", "baseline", 0)])


def test_cpu_info_reads_the_first_processor(tmp_path):
    from paper_lib.common.provenance import cpu_info

    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: Some CPU\nflags\t\t: fpu avx2 avx512f\n\nprocessor\t: 1\n"
                    "model name\t: Other\n")
    assert cpu_info(info) == {"processor": "0", "model name": "Some CPU", "flags": "fpu avx2 avx512f"}
    assert cpu_info(tmp_path / "absent") == {}


def test_a_seed_that_is_not_a_number_is_one_clear_error(capsys):
    from paper_lib.pipeline.verify import main

    with pytest.raises(SystemExit) as exit_:
        main(["--run", "HalfCheetah-v5", "masksembles", "zero"])
    assert exit_.value.code == 2
    assert "integer seed" in capsys.readouterr().err


def test_float32_noise_is_within_tolerance_and_more_is_not(tmp_path):
    from paper_lib.pipeline.verify import FLOAT_TOLERANCE, PASSING

    noise = compare_files(*_pair(tmp_path, "m,auroc\na,0.9\n", f"m,auroc\na,{0.9 + FLOAT_TOLERANCE / 10}\n"))
    assert noise.result == "within tolerance" and noise.result in PASSING
    moved = compare_files(*_pair(tmp_path, "m,auroc\na,0.9\n", f"m,auroc\na,{0.9 + FLOAT_TOLERANCE * 10}\n"))
    assert moved.result == "numbers differ" and moved.result not in PASSING


def _episodes(rewards_by_group: dict[tuple[str, bool], list[float]]) -> str:
    lines = ["inference,deterministic,member,reward,length,env,method,seed"]
    for (inference, deterministic), rewards in rewards_by_group.items():
        lines += [f"{inference},{deterministic},,{r},1000,Walker2d-v5,baseline,0" for r in rewards]
    return "\n".join(lines) + "\n"


def test_reward_episodes_are_judged_as_a_sample_per_group(tmp_path):
    from paper_lib.pipeline.verify import PASSING

    rng = np.random.default_rng(0)
    committed = {("single", True): list(rng.normal(3000, 300, 10)), ("single", False): list(rng.normal(2000, 300, 10))}
    # Chaotic episodes: every episode another number, same distribution (another CPU's last bits).
    same = {group: list(rng.normal(np.mean(r), 300, 10)) for group, r in committed.items()}
    found = compare_files(*_pair(tmp_path, _episodes(committed), _episodes(same)))
    assert found.result == "same distribution" and found.result in PASSING and "Welch" in found.note
    # One group's rewards fell by a third: another distribution, whatever the other group does.
    fell = {**same, ("single", False): [r - 700 for r in committed[("single", False)]]}
    found = compare_files(*_pair(tmp_path, _episodes(committed), _episodes(fell)))
    assert found.result == "numbers differ" and found.result not in PASSING


def test_reward_files_whose_labels_differ_are_another_table(tmp_path):
    committed = {("single", True): [1.0, 2.0, 3.0]}
    relabelled = _episodes(committed).replace("Walker2d-v5", "Ant-v5")
    found = compare_files(*_pair(tmp_path, _episodes(committed), relabelled.replace(",1.0,", ",1.5,")))
    assert found.result == "differs"


def test_float_noise_is_judged_by_the_states_behind_a_number_and_a_tampered_auroc_fails(tmp_path):
    """Issue 71: another CPU swaps a few nearly tied states (ROC tpr 4e-4 at 5000 OOD states, AUPR 1e-5), and a
    std of nearly equal member values loses digits; none of that is a failure, while an AUROC moved by 0.01 is."""
    from paper_lib.pipeline.verify import PASSING

    states = (1000, 5000)
    roc = compare_files(*_pair(tmp_path, "fpr,tpr\n0.1,0.8\n0.2,0.9\n", "fpr,tpr\n0.1,0.8004\n0.2,0.9\n"), states)
    assert roc.result == "within tolerance" and roc.result in PASSING
    assert compare_files(*_pair(tmp_path, "fpr,tpr\n0.1,0.8\n", "fpr,tpr\n0.1,0.8004\n")).result == "numbers differ"
    metrics = "measure,auroc,aupr_in,n_id\nvalue_std,0.90,0.60,1000\n"
    noisy = "measure,auroc,aupr_in,n_id\nvalue_std,0.9000018,0.6000109,1000\n"
    assert compare_files(*_pair(tmp_path, metrics, noisy), states).result == "within tolerance"
    tampered = compare_files(*_pair(tmp_path, metrics, "measure,auroc,aupr_in,n_id\nvalue_std,0.91,0.60,1000\n"),
                             states)
    assert tampered.result == "numbers differ" and tampered.column == "auroc"
    recount = compare_files(*_pair(tmp_path, metrics, "measure,auroc,aupr_in,n_id\nvalue_std,0.90,0.60,1001\n"),
                            states)
    assert recount.result == "numbers differ" and recount.column == "n_id"  # a count is never noise
    values = "step,value_std\n0,0.337\n1,0.05\n2,0.9\n"
    assert compare_files(*_pair(tmp_path, values, "step,value_std\n0,0.3372\n1,0.05\n2,0.9\n")).result \
        == "within tolerance"
    assert compare_files(*_pair(tmp_path, values, "step,value_std\n0,0.347\n1,0.05\n2,0.9\n")).result \
        == "numbers differ"
