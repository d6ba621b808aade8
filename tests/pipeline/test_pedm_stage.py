"""The `pedm` stage (issue 69) on a committed MuJoCo run, with very short episodes and a 2-epoch PEDM.

Real code throughout: the committed HalfCheetah MC Dropout checkpoint plays PEDM's protocol (MC members sample, so
determinism is tested where it can fail), PEDM and the sequence baselines are fit and every scorer is written.
"""

from __future__ import annotations

import json
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from paper_lib.measures.dynamics import PEDMConfig
from paper_lib.ood.pedm_collect import CONDITIONS, play_id, play_tests
from paper_lib.pipeline.config import load_run_config
from paper_lib.pipeline.layout import PEDM_STAGE, Layout, pedm_runs
from paper_lib.ood.datasets import StateDataset
from paper_lib.pipeline.pedm_stage import (FILES, TABLE2_FILES, PEDMSettings, load_agent, main, read_settings,
                                           read_steps, read_table2_scores, run_pedm)
from paper_lib.scoring.pedm_scores import score_collection
from paper_lib.scoring.peer_scores import PEER_DETECTORS, fit_peer_detectors

ROOT = Path(__file__).resolve().parents[2]
RUN = ("HalfCheetah-v5", "mc_dropout", 0)
TINY = PEDMSettings(epochs=2, id_episodes=3, threshold_episodes=2, test_episodes=2, n_bootstrap=20, max_steps=25,
                    injection_step=10)


def _config(root: Path):
    """The paper profile's config over a results tree at `root` holding a copy of RUN's committed checkpoint."""
    cfg = load_run_config(ROOT / "params.yaml")
    cfg = cfg.__class__(**{**cfg.__dict__, "root": root})
    shutil.copytree(ROOT / "results" / cfg.profile / "checkpoints" / RUN[0] / RUN[1] / f"seed{RUN[2]}",
                    cfg.checkpoint_dir(*RUN))
    cfg.dataset_path(*RUN).parent.mkdir(parents=True)
    shutil.copy(ROOT / "results" / cfg.profile / "datasets" / RUN[0] / RUN[1] / f"seed{RUN[2]}.npz",
                cfg.dataset_path(*RUN))
    return cfg


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> Path:
    return run_pedm(_config(tmp_path_factory.mktemp("a")), *RUN, TINY)


def test_the_stage_writes_every_scorer_per_step_with_pedms_labels(written):
    assert sorted(p.name for p in written.iterdir()) == sorted(FILES + TABLE2_FILES)
    steps = read_steps(written / "steps.npz")
    scorers = list(steps["scorers"])
    assert scorers == ["value_std", "policy_std", "policy_js", *PEER_DETECTORS]
    assert list(steps["conditions"]) == [f"{k}/{s}" for k, s in CONDITIONS]
    n = (TINY.threshold_episodes + len(CONDITIONS) * TINY.test_episodes) * TINY.max_steps
    assert steps["scores"].shape == (len(scorers), n) and steps["scores"].dtype == np.float16
    assert np.all(np.isfinite(steps["scores"])) and not (steps["scores"].view(np.uint16) & 3).any()
    cond, label, step = steps["condition"], steps["label"], steps["step"]
    assert np.bincount(cond + 1).tolist() == [TINY.threshold_episodes * TINY.max_steps] + \
        [TINY.test_episodes * TINY.max_steps] * len(CONDITIONS)
    assert not label[cond == -1].any()  # held-out ID episodes
    tests = cond >= 0
    assert np.array_equal(label[tests], (step[tests] >= TINY.injection_step).astype(np.int8))

    metrics = pd.read_csv(written / "metrics.csv")
    per_kind = metrics[metrics["kind"] != "mean"]
    assert len(per_kind) == len(scorers) * len(CONDITIONS) and len(metrics) == len(scorers) * (len(CONDITIONS) + 2)
    assert per_kind["auroc"].between(0, 1).all() and (per_kind["auroc_ci_low"] <= per_kind["auroc_ci_high"]).all()
    assert (per_kind["n_ood"] == TINY.test_episodes * (TINY.max_steps - TINY.injection_step)).all()
    assert set(metrics[["env", "method", "seed"]].itertuples(index=False, name=None)) == {RUN}
    severe = metrics[(metrics["kind"] == "mean") & (metrics["severity"] == "severe") & (metrics["scorer"] == "pedm")]
    assert severe["auroc"].item() == pytest.approx(
        per_kind[(per_kind["severity"] == "severe") & (per_kind["scorer"] == "pedm")]["auroc"].mean())

    from paper_lib.scoring.metrics import injection_metrics

    for i, scorer in enumerate(scorers):  # the metrics recomputed from steps.npz's float16 scores
        part = cond == 5
        again = injection_metrics(steps["scores"][i][part].astype(float), label[part], steps["episode"][part])
        row = per_kind[(per_kind["scorer"] == scorer) & (per_kind["kind"] == CONDITIONS[5][0])
                       & (per_kind["severity"] == CONDITIONS[5][1])]
        assert again["auroc"] == pytest.approx(row["auroc"].item(), abs=0.02), scorer

    fit = pd.read_csv(written / "pedm_fit.csv")
    assert fit["epoch"].tolist() == [1, 2] and fit["val_mse"].notna().all()
    provenance = json.loads((written / "provenance.json").read_text())
    assert provenance["settings"]["epochs"] == 2
    assert set(provenance["sha256"]) == {"model.zip", "vecnormalize.pkl", "dataset"}


def test_pedm_scores_table_2s_states_and_the_table_reads_them(written):
    """The same PEDM scores one transition from each state the `score` stage evaluates; read back as Table 2's row,
    and refused once the dataset they were made from has changed."""
    cfg = _config_over(written)
    metrics, replicates = read_table2_scores(cfg, [RUN, ("HalfCheetah-v5", "baseline", 0), ("Walker2d-v5", *RUN[1:])])
    assert metrics[["ood_set", "measure"]].values.tolist() == [["perturbed", "pedm"], ["noise", "pedm"]]
    assert set(metrics[["env", "method", "seed"]].itertuples(index=False, name=None)) == {RUN}  # the others: no file
    assert metrics["auroc"].between(0, 1).all() and (metrics["auroc_ci_low"] <= metrics["auroc"]).all()
    n_id = int((metrics["n_id"]).iloc[0])
    assert n_id > 0 and metrics["n_ood"].tolist()[0] == 5000  # every perturbed state of the dataset
    assert sorted(replicates) == [(*RUN, "noise", "pedm"), (*RUN, "perturbed", "pedm")]
    assert all(len(r) == TINY.n_bootstrap for r in replicates.values())

    data = StateDataset.load(cfg.dataset_path(*RUN))
    data.states[0, 0] += 1e-3
    data.save(cfg.dataset_path(*RUN))
    with pytest.raises(ValueError, match=r"were made from dataset SHA-256 .* pedm@HalfCheetah-v5-mc_dropout-0"):
        read_table2_scores(cfg, [RUN])


def _config_over(written: Path):
    """The config whose results tree holds `written` (a copy, so a test may change its files)."""
    root = next(p for p in written.parents if p.name == "results").parent
    copy = root.parent / f"{root.name}-copy"
    shutil.copytree(root, copy)
    cfg = load_run_config(ROOT / "params.yaml")
    return cfg.__class__(**{**cfg.__dict__, "root": copy})


def test_the_same_run_gives_the_same_bytes(written, tmp_path):
    again = run_pedm(_config(tmp_path), *RUN, TINY)
    for name in FILES + TABLE2_FILES:
        assert (again / name).read_bytes() == (written / name).read_bytes(), name


def test_a_steps_scores_do_not_depend_on_its_batch():
    """The detectors score an episode alone as among others; the agent's measures (MC samples seeded per state of
    the collection, `measures.estimates`) whatever the batch size."""
    from paper_lib.measures.estimates import uncertainty

    cfg = load_run_config(ROOT / "params.yaml")
    cfg = cfg.__class__(**{**cfg.__dict__, "root": ROOT})
    agent = load_agent(cfg.checkpoint_dir(*RUN), *RUN)
    detectors = fit_peer_detectors(play_id(agent, RUN[0], 0, 3, max_steps=20), 0, replace(PEDMConfig(), epochs=1))
    data = play_tests(agent, RUN[0], 0, 3, max_steps=20, injection_step=5)[("act_noise", "severe")]
    last = data["episode"] == 2
    whole = score_collection(data, detectors, lambda obs: {})
    alone = score_collection({k: v[last] for k, v in data.items()}, detectors, lambda obs: {})
    assert list(whole) == list(PEER_DETECTORS)
    for name in whole:
        assert np.array_equal(whole[name][last], alone[name]), name
    batched = [score_collection(data, detectors, lambda obs, b=b: uncertainty(agent.model, agent.policy_obs(obs),
                                                                           batch_size=b, seed=0)) for b in (7, 1024)]
    assert list(batched[0]) == ["value_std", "policy_std", "policy_js", *PEER_DETECTORS]
    for name in batched[0]:
        assert np.array_equal(batched[0][name], batched[1][name]), name


def test_bad_input_is_one_clear_error(tmp_path, capsys):
    cfg = _config(tmp_path)
    with pytest.raises(ValueError, match="MuJoCo envs"):
        run_pedm(cfg, "SeaquestNoFrameskip-v4", "baseline", 0, TINY)
    with pytest.raises(FileNotFoundError, match="model.zip is missing"):
        run_pedm(cfg, "Ant-v5", "baseline", 0, TINY)
    with pytest.raises(ValueError, match="pedm.epochs must be a positive integer"):
        PEDMSettings(epochs=0)
    params = tmp_path / "params.yaml"
    text = (ROOT / "params.yaml").read_text()
    params.write_text(re.sub(r"\npedm:\n(  .*\n)+", "\n", text))
    with pytest.raises(ValueError, match="has no `pedm` section"):
        read_settings(params, 10)
    params.write_text(text.replace("  test_episodes: 20", "  test_episodes: 20\n  epoch: 3"))
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['epoch'\]"):
        read_settings(params, 10)
    assert read_settings(ROOT / "params.yaml", 10).test_episodes == 20
    with pytest.raises(SystemExit):
        main(["HalfCheetah-v5", "baseline", "99", "--params", str(ROOT / "params.yaml")])
    assert "is not a run of profile" in capsys.readouterr().err


def test_the_stage_exists_for_the_mujoco_runs_only():
    runs = [("HalfCheetah-v5", "baseline", 0), ("SeaquestNoFrameskip-v4", "baseline", 0)]
    assert pedm_runs(runs) == runs[:1]
    layout = Layout.of("/repo", "paper")
    assert layout.stage_paths(PEDM_STAGE, runs[0]).outs == (Path("/repo/results/paper/pedm/HalfCheetah-v5/baseline/seed0"),)
    with pytest.raises(ValueError, match="per MuJoCo run"):
        layout.stage_paths(PEDM_STAGE, runs[1])


def test_steps_frame_gives_back_the_stored_steps_with_inf_as_the_largest_float(tmp_path):
    """steps.npz's float16 saturates above 65504 (+inf); read back, it is the largest float, above every other score,
    and the conditions come back as (kind, severity) pairs."""
    from paper_lib.pipeline.pedm_stage import _npz_bytes, steps_arrays, steps_frame

    steps = pd.DataFrame({"condition": [-1, -1, 0, 0], "episode": [0, 0, 0, 0], "step": [0, 1, 0, 1],
                          "label": [0, 0, 0, 1], "pedm": [0.5, 1.0, 2.0, 1e6]})
    with pytest.warns(RuntimeWarning, match="overflow"):  # 1e6 has no float16: it is stored as +inf
        arrays = steps_arrays(steps, [("act_noise", "severe")])
    (tmp_path / "steps.npz").write_bytes(_npz_bytes(arrays))
    frame, conditions = steps_frame(tmp_path / "steps.npz")
    assert conditions == [("act_noise", "severe")]
    assert list(frame.columns) == ["condition", "episode", "step", "label", "pedm"]
    assert frame["pedm"].tolist() == [0.5, 1.0, 2.0, np.finfo(float).max]
    assert frame[["condition", "step", "label"]].values.tolist() == [[-1, 0, 0], [-1, 1, 0], [0, 0, 0], [0, 1, 1]]
