"""dvc.yaml and paper_lib/pipeline/layout.py name the same paths under results/, stage by stage.

The layout module is the one home of the artifact paths; dvc.yaml spells them again (DVC reads no Python).
Each stage of dvc.yaml, expanded by DVC itself (`foreach` over runs.yaml, `${run.profile}` from params.yaml),
must name exactly the paths `Layout.stage_paths` gives for it in its deps, its outs and its command line,
so a path renamed in one of the two places fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from paper_lib.pipeline.layout import (
    COMMON_STAGE,
    CONDITIONAL_TABLES,
    FIGURE_FORMATS,
    NOTEBOOKS,
    PEDM_STAGE,
    RUN_STAGES,
    SEQUENCE_STAGE,
    STAGE_TABLES,
    TABLE_FORMATS,
    Layout,
    StagePaths,
    common_runs,
    pedm_runs,
    sequence_runs,
)
from paper_lib.pipeline.run_list import PEDM_KEY, SEQUENCE_KEY, read_run_list
from paper_lib.pipeline.status import stage_suffix

ROOT = Path(__file__).resolve().parents[2]
#: A path under results/ on a command line (not one inside another word, as in notebooks/results.ipynb).
RESULTS_PATH = re.compile(r"(?<![\w/.])results/[^\s'\"]+")


def dvc_stages(root: Path = ROOT) -> dict[str, StagePaths]:
    """Every stage of dvc.yaml as DVC expands it: its deps, outs and command-line paths under results/."""
    from dvc.repo import Repo

    stages = {}
    with Repo(str(root)) as repo:
        for stage in repo.index.stages:
            deps = tuple(Path(d.def_path) for d in stage.deps if str(d.def_path).startswith("results/"))
            outs = tuple(Path(o.def_path) for o in stage.outs if str(o.def_path).startswith("results/"))
            command = tuple(Path(p) for p in RESULTS_PATH.findall(stage.cmd))
            stages[stage.name] = StagePaths(deps=deps, outs=outs, command=command)
    return stages


def mismatches(stages: dict[str, StagePaths], layout: Layout, runs: list[tuple[str, str, int]]) -> list[str]:
    """Where dvc.yaml's stages and the layout differ: one line per stage and part, with what is extra or missing."""
    played = read_run_list(ROOT, PEDM_KEY)[1]  # the MuJoCo runs whose PEDM protocol has run (runs.yaml)
    assert played == [run for run in pedm_runs(runs) if (layout.pedm_dir(*run) / "metrics.csv").is_file()], played
    expected = {f"{stage}@{stage_suffix(*run)}": layout.stage_paths(stage, run) for stage in RUN_STAGES for run in runs}
    expected |= {f"{COMMON_STAGE}@{stage_suffix(*run)}": layout.stage_paths(COMMON_STAGE, run) for run in common_runs(runs)}
    expected |= {f"{PEDM_STAGE}@{stage_suffix(*run)}": layout.stage_paths(PEDM_STAGE, run) for run in played}
    assert read_run_list(ROOT, SEQUENCE_KEY)[1] == sequence_runs(runs)  # every MuJoCo run (runs.yaml)
    expected |= {f"{SEQUENCE_STAGE}@{stage_suffix(*run)}": layout.stage_paths(SEQUENCE_STAGE, run)
                 for run in sequence_runs(runs)}
    expected |= {stage: layout.stage_paths(stage) for stage in layout.stage_names() if stage not in RUN_STAGES}
    problems = [f"stage {name}: in dvc.yaml, not in the layout (paper_lib/pipeline/layout.py)"
                for name in sorted(set(stages) - set(expected))]
    problems += [f"stage {name}: in the layout, not in dvc.yaml" for name in sorted(set(expected) - set(stages))]
    for name in sorted(set(stages) & set(expected)):
        for part in ("deps", "outs", "command"):
            found, wanted = set(getattr(stages[name], part)), set(getattr(expected[name], part))
            if found != wanted:
                problems.append(f"stage {name} {part}: dvc.yaml has {sorted(map(str, found - wanted))} that the layout "
                                f"does not, the layout has {sorted(map(str, wanted - found))} that dvc.yaml does not")
    return problems


@pytest.fixture(scope="module")
def expanded() -> dict[str, StagePaths]:
    return dvc_stages()


def test_dvc_yaml_names_the_paths_of_the_layout(expanded):
    profile, runs = read_run_list(ROOT)
    assert runs, "runs.yaml lists no run: the per-run stages would go unchecked"
    any_out = next(path for paths in expanded.values() for path in paths.outs)
    assert any_out.parts[:2] == ("results", profile), f"dvc.yaml expanded for another profile than runs.yaml's: {any_out}"
    problems = mismatches(expanded, Layout.of(".", profile), runs)
    assert not problems, "dvc.yaml and paper_lib/pipeline/layout.py disagree:\n" + "\n".join(problems)


def test_a_renamed_path_is_caught(expanded):
    """The check is real: one out renamed, one dep dropped, one stage added, each is reported."""
    profile, runs = read_run_list(ROOT)
    layout = Layout.of(".", profile)
    score = f"score@{stage_suffix(*runs[0])}"
    changed = dict(expanded)
    changed[score] = StagePaths(deps=expanded[score].deps[:1], outs=tuple(
        path.with_name(path.name + "-renamed") for path in expanded[score].outs), command=())
    changed["rewards"] = StagePaths(deps=expanded["rewards"].deps, outs=tuple(
        Path(str(p).replace("rewards_long", "reward_long")) for p in expanded["rewards"].outs),
        command=expanded["rewards"].command)
    changed["extra"] = StagePaths()
    problems = mismatches(changed, layout, runs)
    assert any(p.startswith(f"stage {score} outs:") and "-renamed" in p for p in problems), problems
    assert any(p.startswith(f"stage {score} deps:") and ".npz" in p for p in problems), problems
    assert any(p.startswith("stage rewards outs:") and "reward_long.csv" in p for p in problems), problems
    assert "stage extra: in dvc.yaml, not in the layout (paper_lib/pipeline/layout.py)" in problems


def test_the_layout_matches_what_the_writers_write(tmp_path):
    """TABLE_FORMATS and FIGURE_FORMATS are the files save_table and save_figure write for one stem."""
    import pandas as pd
    from matplotlib.figure import Figure

    from paper_lib.reporting.plots import save_figure
    from paper_lib.reporting.tables import save_table

    layout = Layout(tmp_path)
    layout.tables.mkdir()
    layout.figures.mkdir()
    save_table(pd.DataFrame({"a": [1.0]}), layout.tables / "t", caption="a table")
    save_figure(Figure(), layout.figures / "f")
    assert sorted(layout.tables.iterdir()) == sorted(layout.table_files("t"))
    assert sorted(layout.figures.iterdir()) == sorted(layout.figure_files("f"))
    assert (TABLE_FORMATS, FIGURE_FORMATS) == (("csv", "md", "tex"), ("png", "pdf"))


def test_the_notebooks_write_the_tables_the_layout_names():
    """Each stage's notebook spells every table stem the layout gives it (the notebooks keep their own paths)."""
    import json

    for stage, stems in {**STAGE_TABLES, **CONDITIONAL_TABLES}.items():
        notebook = json.loads((ROOT / "notebooks" / f"{NOTEBOOKS[stage]}.ipynb").read_text())
        source = "".join("".join(cell["source"]) for cell in notebook["cells"] if cell["cell_type"] == "code")
        written = set(re.findall(r"[\"']([a-z_]+)[\"']", source))
        written |= {f"{prefix}{suffix}" for prefix in re.findall(r"f[\"']([a-z_]+)\{", source)
                    for suffix in ("perturbed", "noise")}  # ood_auroc_{ood_set}
        missing = [stem for stem in stems if stem not in written]
        assert not missing, f"notebooks/{NOTEBOOKS[stage]}.ipynb does not name {missing} (layout.STAGE_TABLES)"


def test_main_tree_paths():
    """The per-run paths, and the ensembles' trees laid out as the main one."""
    layout = Layout.of("/repo", "cpu")
    run = ("Ant-v5", "ensemble", 2)
    assert layout.checkpoint_dir(*run) == Path("/repo/results/cpu/checkpoints/Ant-v5/ensemble/seed2")
    assert layout.run_path("dataset", *run) == Path("/repo/results/cpu/datasets/Ant-v5/ensemble/seed2.npz")
    assert layout.run_path("evaluation", *run) == Path("/repo/results/cpu/evaluations/Ant-v5/ensemble/seed2.csv")
    assert layout.run_path("scores", *run) == Path("/repo/results/cpu/scores/Ant-v5/ensemble/seed2")
    own = layout.part("own")
    assert own.checkpoint_dir(*run) == Path("/repo/results/cpu/own/checkpoints/Ant-v5/ensemble/seed2")
    assert layout.part("independent").combination_metrics("Ant-v5", (0, 1, 2, 3)) == Path(
        "/repo/results/cpu/independent/scores/Ant-v5/members-0-1-2-3/metrics.csv")
    assert layout.scaling_dir("Ant-v5", "baseline", 64, 0) == Path("/repo/results/cpu/scaling/Ant-v5/baseline/w64/seed0")
    for bad in (lambda: layout.run_path("model", *run), lambda: layout.part("shared"),
                lambda: layout.recording("frames"), lambda: layout.stage_paths("score"),
                lambda: layout.stage_paths("rewards", run), lambda: layout.stage_paths("nope")):
        with pytest.raises(ValueError):
            bad()


def test_the_paths_the_notebooks_ask_for():
    """Tables and figures by stem (a stem no stage declares is refused), the folders stages write whole, and the
    files the notebooks read beside them."""
    layout = Layout.of("/repo", "cpu")
    tree = Path("/repo/results/cpu")
    assert layout.table("rewards_long") == tree / "tables" / "rewards_long"
    assert layout.table("ood_metrics", "csv") == tree / "tables" / "ood_metrics.csv"
    assert layout.table("ood_source_coverage", "md") == tree / "tables" / "ood_source_coverage.md"  # conditional
    assert layout.figure("training_curves") == tree / "figures" / "training_curves"
    assert layout.figure("auroc_profiles", "pdf") == tree / "figures" / "auroc_profiles.pdf"
    assert layout.table_files("rewards") == tuple(layout.table("rewards", fmt) for fmt in TABLE_FORMATS)
    assert layout.figure_files("reward_profiles") == tuple(layout.figure("reward_profiles", fmt) for fmt in FIGURE_FORMATS)
    assert layout.table_folder("study") == tree / "tables" / "study"
    assert layout.figure_folder("uncertainty_over_time") == tree / "figures" / "over_time"
    assert layout.reward_episodes == tree / "tables" / "reward_episodes.csv"
    assert layout.training_curve("Ant-v5", "ensemble", 2) == tree / "checkpoints/Ant-v5/ensemble/seed2/training_curve.csv"
    assert layout.spawn_file("rollouts") == tree / "spawn" / "rollouts.csv"
    assert layout.guard_dir("Ant-v5", "ensemble", 2) == tree / "guards/Ant-v5/ensemble/seed2"
    for bad in (lambda: layout.table("reward_long"), lambda: layout.table("rewards", "png"),
                lambda: layout.figure("rewards"), lambda: layout.figure("training_curves", "csv"),
                lambda: layout.table_folder("rewards"), lambda: layout.figure_folder("nope"),
                lambda: layout.spawn_file("frames")):
        with pytest.raises(ValueError):
            bad()


def test_the_commands_that_call_dvc_name_its_stages():
    """`make reproduce` / `make recollect` call stages by name; each is one the layout (and so dvc.yaml) has."""
    from paper_lib.pipeline.reproduce import EXPERIMENT_STAGES, RECORDING_STAGES, TABLE_STAGES

    named = set(Layout.of(".", "cpu").stage_names())
    assert set(TABLE_STAGES + EXPERIMENT_STAGES + RECORDING_STAGES) <= named


def test_the_ensembles_trees_are_the_layouts_parts():
    """The ensembles' RunConfig mirrors (profile `<profile>/own`) sit where the layout puts its parts."""
    from paper_lib.experiments.ensembles import load_ensembles_config

    cfg = load_ensembles_config(ROOT / "params.yaml")
    main = cfg.run.layout
    assert cfg.independent.results == main.part("independent").results
    assert cfg.own.checkpoint_dir("Swimmer-v5", "ensemble", 1) == main.part("own").checkpoint_dir("Swimmer-v5",
                                                                                                  "ensemble", 1)
    assert cfg.combination_dataset("Walker2d-v5", (0, 1, 2, 3)) == (
        main.results / "independent" / "datasets" / "Walker2d-v5" / "members-0-1-2-3.npz")
