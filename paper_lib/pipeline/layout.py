"""Where every artifact lives under results/: the one home of the paths the pipeline reads and writes.

Every path below results/<profile>/ is built here; `RunConfig`, the per-run stages, the status, the
experiments and the study ask this module for theirs. `Layout.stage_paths` says, stage by stage, which
of them dvc.yaml names, and tests/pipeline/test_pipeline_layout.py checks dvc.yaml (expanded over runs.yaml) names
exactly those: a path renamed here or there and not in both places fails that test.

    results/<profile>/                                 Layout(root / "results" / profile)
      checkpoints/<env>/<method>/seed<s>/                a trained run            (train)
        training_curve.csv                                 its training curve
      datasets/<env>/<method>/seed<s>.npz                its ID and OOD states    (collect)
      evaluations/<env>/<method>/seed<s>.csv             its reward episodes      (evaluate)
      scores/<env>/<method>/seed<s>/                     its OOD scores           (score)
      common_scores/<env>/<method>/seed<s>/              a member run on the baseline's states of its seed (common_score)
      pedm/<env>/<method>/seed<s>/                       a MuJoCo run under PEDM's protocol (pedm, issue 69)
      sequence_scores/<env>/<method>/seed<s>/            the sequence detectors on a MuJoCo run's dataset (sequence_score)
      pedm/budget_curve.csv, budget_auroc.csv            PEDM's validation curve and AUROC probes that chose its epochs
      tables/pedm_protocol_runs.csv                      every run's PEDM-protocol metrics, as notebook 14 read them
      tables/<stem>.{csv,md,tex}, figures/<stem>.{png,pdf}   what the notebooks make (STAGE_TABLES, STAGE_FIGURES)
      tables/<folder>/, figures/<folder>/                what a notebook writes whole (STAGE_TABLE_FOLDERS, ...)
      tables/reward_episodes.csv                         every evaluation episode, as notebook 02 read them
      notebooks/<notebook>.ipynb                         each executed notebook (NOTEBOOKS)
      notebooks/train/<env>-<method>-seed<s>.ipynb       each run's executed training notebook
      recordings/{example_states,quickstart}.npz         simulated material notebooks 07 and 00 draw
      guards/<env>/<method>/seed<s>/                     the guard experiment's replay of a run
      spawn/{rollouts,summary}.csv, value_level/         the experiments' rows per run
      studies/studies.db                                 the Optuna study database
      scaling/<env>/<method>/w<width>/seed<s>/           the scaling runs
      independent/, own/                                 the ensembles' trees, laid out as this one (ENSEMBLE_PARTS)
      runs.md                                            which runs exist (paper_lib.pipeline.status)

The notebooks and scripts ask a Layout (through `RunConfig.layout` where they have a config) for the paths
under results/<profile>/ they read and write; the quickstart takes its paths as parameters, which dvc.yaml
passes. They still spell the stems of their tables and figures (their committed executions hold their source):
`Layout.table` and `Layout.figure` refuse a stem that STAGE_TABLES (or CONDITIONAL_TABLES) and STAGE_FIGURES do
not name, so a notebook cannot write a table dvc.yaml does not know of; the files inside a folder a stage writes
whole (`Layout.table_folder`, `Layout.figure_folder`) are the stage's own.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: One run of the matrix: (env id, method, seed).
Run = tuple[str, str, int]

RESULTS = "results"
#: Where runs and study databases of another recipe are moved before they are trained again (outside results/).
REPLACED = "build/replaced"
#: The per-run artifacts, in pipeline order, and the folder that holds each kind.
RUN_FOLDERS = {"checkpoint": "checkpoints", "dataset": "datasets", "evaluation": "evaluations", "scores": "scores"}
#: The two trees of notebook 11 beside the main one: independently trained members, and `own` runs.
ENSEMBLE_PARTS = ("independent", "own")
#: The run notebook 00 (the quickstart) shows, and whose episode `record_quickstart` records.
QUICKSTART_RUN: Run = ("HalfCheetah-v5", "masksembles", 0)
#: What `reporting.tables.save_table` writes per stem, and `reporting.plots.save_figure` (tests check both).
TABLE_FORMATS = ("csv", "md", "tex")
FIGURE_FORMATS = ("png", "pdf")
#: The recordings notebooks draw instead of simulating (paper_lib.experiments.recordings).
RECORDINGS = ("example_states", "quickstart")
#: A checkpoint folder's training curve (paper_lib.agents.training writes it beside CHECKPOINT_FILES).
TRAINING_CURVE = "training_curve.csv"
#: The spawn experiment's rows (notebook 12), each a CSV under spawn/.
SPAWN_FILES = ("rollouts", "summary")
#: Every evaluation episode the `rewards` stage read, one CSV under tables/ beside its tables.
REWARD_EPISODES = "reward_episodes.csv"
#: Every PEDM-protocol metric the `pedm_protocol` stage read (one row per run, scorer, kind and severity), under tables/.
PEDM_PROTOCOL_RUNS = "pedm_protocol_runs.csv"

#: The executed notebook of each notebook stage, under notebooks/ (the source is notebooks/<name>.ipynb too).
NOTEBOOKS = {"quickstart": "00_quickstart", "rewards": "02_rewards", "ood": "03_ood_detection",
             "uncertainty_over_time": "04_uncertainty_over_time",
             "training_and_perturbations": "05_training_and_perturbations", "paper_vs_us": "06_paper_vs_us",
             "example_states": "07_example_states", "guard": "08_guard", "study": "09_study", "scaling": "10_scaling",
             "ensembles": "11_ensembles", "spawn": "12_spawn", "value_level": "13_value_level",
             "pedm_protocol": "14_pedm_protocol"}
#: The tables each stage writes directly under tables/ (each in every TABLE_FORMATS).
STAGE_TABLES = {
    "rewards": ("rewards", "rewards_long", "reward_repeated_games", "reward_vs_baseline", "reward_aggregates",
                "reward_improvement"),
    "ood": ("auroc_between_methods", "auroc_between_methods_own", "auroc_aggregates", "auroc_improvement", "ood_trivially_separable", "ood_metrics",
            "ood_auroc_perturbed", "ood_auroc_noise", "auroc_vs_detectors", "auroc_members_vs_baseline"),
    "training_and_perturbations": ("perturbation_ratios",),
    "paper_vs_us": ("paper_claims", "paper_vs_us_rewards", "paper_vs_us_auroc"),
    "spawn": ("spawn_uncertainty",),
    "value_level": ("value_level",),
    "pedm_protocol": ("pedm_protocol",),
}
#: Tables a stage writes only where the profile has what they show, so not DVC outputs (DVC needs each output
#: to exist): the Atari OOD sources against the agents' own play.
CONDITIONAL_TABLES = {"ood": ("ood_source_coverage",)}
#: The figures each stage writes directly under figures/ (each in every FIGURE_FORMATS).
STAGE_FIGURES = {"rewards": ("reward_profiles",), "ood": ("roc_value_policy", "roc_policy_js", "auroc_profiles",
                                                                       "auroc_intervals"),
                 "training_and_perturbations": ("training_curves",)}
#: The folders under tables/ and figures/ a stage writes whole (named as the stage, except where given).
STAGE_FIGURE_FOLDERS = {"uncertainty_over_time": ("over_time",), "training_and_perturbations": ("perturbation_bars",),
                        "example_states": ("example_states",), "quickstart": ("quickstart",), "guard": ("guard",),
                        "spawn": ("spawn",), "value_level": ("value_level",), "study": ("study",),
                        "scaling": ("scaling",), "ensembles": ("ensembles",),
                        "pedm_protocol": ("pedm_protocol",)}
STAGE_TABLE_FOLDERS = {"guard": ("guard",), "study": ("study",), "scaling": ("scaling",), "ensembles": ("ensembles",)}
#: Every stem of a table written directly under tables/, and of a figure under figures/ (what `Layout.table` and
#: `Layout.figure` accept).
TABLE_STEMS = frozenset(stem for stems in (*STAGE_TABLES.values(), *CONDITIONAL_TABLES.values()) for stem in stems)
FIGURE_STEMS = frozenset(stem for stems in STAGE_FIGURES.values() for stem in stems)
#: The tables `paper_vs_us` reads (as CSV), each written by `rewards` or `ood`.
PAPER_VS_US_READS = ("rewards_long", "ood_metrics", "reward_vs_baseline", "auroc_vs_detectors", "auroc_between_methods")
#: The per-run stages of dvc.yaml (`foreach` over runs.yaml), in pipeline order.
RUN_STAGES = ("train", "collect", "evaluate", "score")
#: The per-run stage of the member runs whose seed has a baseline run (`common_runs`; runs.yaml's common_runs).
COMMON_STAGE = "common_score"
#: The per-run stage of PEDM's protocol (issue 69), for the MuJoCo runs (`pedm_runs`; runs.yaml's pedm_runs).
PEDM_STAGE = "pedm"
#: The per-run stage of the sequence detectors on a MuJoCo run's main dataset (issue 69; runs.yaml's sequence_runs).
SEQUENCE_STAGE = "sequence_score"


def results_dir(root: str | Path, profile: str) -> Path:
    """results/<profile>/ below the repository root `root`."""
    return Path(root) / RESULTS / profile


#: Whose states every member method also scores, for comparisons between methods on one state set (issue 66).
COMMON_STATES_OF = "baseline"


def common_runs(runs: list[Run]) -> list[Run]:
    """The member runs among `runs` whose (env, seed) has a baseline run to take the states from
    (paper_lib/pipeline/common_states.py scores them; runs.yaml's `common_runs`)."""
    listed = set(runs)
    return [run for run in runs if run[1] != COMMON_STATES_OF and (run[0], COMMON_STATES_OF, run[2]) in listed]


def pedm_runs(runs: list[Run]) -> list[Run]:
    """The runs among `runs` that PEDM's protocol applies to: the MuJoCo ones (paper_lib/pipeline/pedm_stage.py)."""
    from paper_lib.agents.envs import MUJOCO_ENVS

    return [run for run in runs if run[0] in MUJOCO_ENVS]


def sequence_runs(runs: list[Run]) -> list[Run]:
    """The runs among `runs` whose states the sequence detectors score (paper_lib/pipeline/sequence_stage.py): the
    MuJoCo ones, whose observations are vectors (an Atari frame stack has 28k dimensions, one forest each)."""
    return pedm_runs(runs)


def seed_name(seed: int) -> str:
    return f"seed{seed}"


def stage_suffix(env_id: str, method: str, seed: int) -> str:
    """The `<env>-<method>-<seed>` part of a per-run stage name in dvc.yaml (`score@HalfCheetah-v5-baseline-0`)."""
    return f"{env_id}-{method}-{seed}"


#: What a checkpoint folder holds once its run has landed (paper_lib.agents.training writes both last).
CHECKPOINT_FILES = ("model.zip", "config.json")


def combination_name(members: tuple[int, ...]) -> str:
    """An independent ensemble's name from its members' seeds: members-0-1-2-3."""
    return "members-" + "-".join(map(str, members))


@dataclass(frozen=True)
class StagePaths:
    """The paths under results/ one dvc.yaml stage names: its deps, its outs, and those on its command line."""

    deps: tuple[Path, ...] = ()
    outs: tuple[Path, ...] = ()
    command: tuple[Path, ...] = ()


@dataclass(frozen=True)
class Layout:
    """The files of one results tree: results/<profile>/, or a tree laid out like it (results/<profile>/own/)."""

    results: Path

    @classmethod
    def of(cls, root: str | Path, profile: str) -> Layout:
        return cls(results_dir(root, profile))

    # --- one run --------------------------------------------------------------------------------
    def folder(self, artifact: str) -> Path:
        """The folder of one per-run artifact kind (a key of RUN_FOLDERS) across the tree's runs."""
        if artifact not in RUN_FOLDERS:
            raise ValueError(f"unknown artifact {artifact!r}; use one of {list(RUN_FOLDERS)}")
        return self.results / RUN_FOLDERS[artifact]

    def checkpoint_dir(self, env_id: str, method: str, seed: int) -> Path:
        return self.folder("checkpoint") / env_id / method / seed_name(seed)

    def has_checkpoint(self, env_id: str, method: str, seed: int) -> bool:
        """Whether the run has landed: its checkpoint folder holds CHECKPOINT_FILES."""
        folder = self.checkpoint_dir(env_id, method, seed)
        return all((folder / name).is_file() for name in CHECKPOINT_FILES)

    def dataset_path(self, env_id: str, method: str, seed: int) -> Path:
        return self.folder("dataset") / env_id / method / f"{seed_name(seed)}.npz"

    def evaluation_path(self, env_id: str, method: str, seed: int) -> Path:
        return self.folder("evaluation") / env_id / method / f"{seed_name(seed)}.csv"

    def scores_dir(self, env_id: str, method: str, seed: int) -> Path:
        return self.folder("scores") / env_id / method / seed_name(seed)

    def run_path(self, artifact: str, env_id: str, method: str, seed: int) -> Path:
        """The path of one run's artifact (a key of RUN_FOLDERS)."""
        build = {"checkpoint": self.checkpoint_dir, "dataset": self.dataset_path,
                 "evaluation": self.evaluation_path, "scores": self.scores_dir}
        if artifact not in build:
            raise ValueError(f"unknown artifact {artifact!r}; use one of {list(RUN_FOLDERS)}")
        return build[artifact](env_id, method, seed)

    def training_curve(self, env_id: str, method: str, seed: int) -> Path:
        """The training curve a run's checkpoint folder holds (TRAINING_CURVE)."""
        return self.checkpoint_dir(env_id, method, seed) / TRAINING_CURVE

    def train_notebook(self, env_id: str, method: str, seed: int) -> Path:
        """The executed training notebook of one run (the `train` stage's)."""
        return self.notebooks / "train" / f"{env_id}-{method}-{seed_name(seed)}.ipynb"

    # --- what the notebooks make -------------------------------------------------------------------
    @property
    def tables(self) -> Path:
        return self.results / "tables"

    @property
    def figures(self) -> Path:
        return self.results / "figures"

    @property
    def notebooks(self) -> Path:
        return self.results / "notebooks"

    def notebook(self, stage: str) -> Path:
        """The executed notebook of a notebook stage (a key of NOTEBOOKS)."""
        return self.notebooks / f"{NOTEBOOKS[stage]}.ipynb"

    def table(self, stem: str, fmt: str | None = None) -> Path:
        """A table a stage writes under tables/ (a stem of TABLE_STEMS): the path without suffix that
        `reporting.tables.save_table` takes, or with `fmt` (one of TABLE_FORMATS) that one of its files."""
        return _with_format(self.tables / _known_stem(stem, TABLE_STEMS, "table", "STAGE_TABLES"), fmt, TABLE_FORMATS)

    def figure(self, stem: str, fmt: str | None = None) -> Path:
        """A figure a stage writes under figures/ (a stem of FIGURE_STEMS): the path without suffix that
        `reporting.plots.show_figure` takes, or with `fmt` (one of FIGURE_FORMATS) that one of its files."""
        return _with_format(self.figures / _known_stem(stem, FIGURE_STEMS, "figure", "STAGE_FIGURES"), fmt,
                            FIGURE_FORMATS)

    def table_folder(self, stage: str) -> Path:
        """The folder under tables/ that `stage` writes whole (STAGE_TABLE_FOLDERS)."""
        return self.tables / _only_folder(STAGE_TABLE_FOLDERS, stage, "tables")

    def figure_folder(self, stage: str) -> Path:
        """The folder under figures/ that `stage` writes whole (STAGE_FIGURE_FOLDERS)."""
        return self.figures / _only_folder(STAGE_FIGURE_FOLDERS, stage, "figures")

    @property
    def reward_episodes(self) -> Path:
        """Every evaluation episode the `rewards` stage read (REWARD_EPISODES)."""
        return self.tables / REWARD_EPISODES

    def table_files(self, stem: str) -> tuple[Path, ...]:
        """The files of one table under tables/, one per format."""
        return tuple(self.tables / f"{stem}.{fmt}" for fmt in TABLE_FORMATS)

    def figure_files(self, stem: str) -> tuple[Path, ...]:
        """The files of one figure under figures/, one per format."""
        return tuple(self.figures / f"{stem}.{fmt}" for fmt in FIGURE_FORMATS)

    @property
    def pedm_protocol_runs(self) -> Path:
        """Every PEDM-protocol metric the `pedm_protocol` stage read (PEDM_PROTOCOL_RUNS)."""
        return self.tables / PEDM_PROTOCOL_RUNS

    @property
    def status_file(self) -> Path:
        """runs.md: which runs exist and what each has."""
        return self.results / "runs.md"

    # --- recordings and experiments ------------------------------------------------------------------
    def recording(self, what: str) -> Path:
        """A recording notebooks draw (one of RECORDINGS)."""
        if what not in RECORDINGS:
            raise ValueError(f"unknown recording {what!r}; use one of {list(RECORDINGS)}")
        return self.results / "recordings" / f"{what}.npz"

    @property
    def guards(self) -> Path:
        return self.results / "guards"

    def guard_dir(self, env_id: str, method: str, seed: int) -> Path:
        """Where the guard experiment keeps one run's replay and guards."""
        return self.guards / env_id / method / seed_name(seed)

    @property
    def spawn(self) -> Path:
        return self.results / "spawn"

    def spawn_file(self, what: str) -> Path:
        """One of the spawn experiment's CSVs (one of SPAWN_FILES)."""
        if what not in SPAWN_FILES:
            raise ValueError(f"unknown spawn file {what!r}; use one of {list(SPAWN_FILES)}")
        return self.spawn / f"{what}.csv"

    @property
    def value_level(self) -> Path:
        return self.results / "value_level"

    @property
    def studies(self) -> Path:
        return self.results / "studies"

    @property
    def studies_db(self) -> Path:
        return self.studies / "studies.db"

    @property
    def scaling(self) -> Path:
        return self.results / "scaling"

    def scaling_dir(self, env_id: str, method: str, width: int, seed: int) -> Path:
        """One scaling run (a network width) of the study."""
        return self.scaling / env_id / method / f"w{width}" / seed_name(seed)

    # --- the ensembles' trees --------------------------------------------------------------------------
    def part(self, name: str) -> Layout:
        """The tree of one ensembles part (one of ENSEMBLE_PARTS), laid out as this one."""
        if name not in ENSEMBLE_PARTS:
            raise ValueError(f"unknown ensembles part {name!r}; use one of {list(ENSEMBLE_PARTS)}")
        return Layout(self.results / name)

    def combination_dataset(self, env_id: str, members: tuple[int, ...]) -> Path:
        """The states of an independent ensemble (in the `independent` tree)."""
        return self.folder("dataset") / env_id / f"{combination_name(members)}.npz"

    def combination_evaluation(self, env_id: str, members: tuple[int, ...]) -> Path:
        return self.folder("evaluation") / env_id / f"{combination_name(members)}.csv"

    def combination_metrics(self, env_id: str, members: tuple[int, ...]) -> Path:
        return self.folder("scores") / env_id / combination_name(members) / "metrics.csv"

    # --- dvc.yaml ------------------------------------------------------------------------------------------
    def common_scores_dir(self, env_id: str, method: str, seed: int) -> Path:
        """A member run's scores on the baseline's states of its seed (paper_lib/pipeline/common_states.py)."""
        return self.results / "common_scores" / env_id / method / seed_name(seed)

    def pedm_dir(self, env_id: str, method: str, seed: int) -> Path:
        """A MuJoCo run's per-step scores and metrics under PEDM's protocol (paper_lib/pipeline/pedm_stage.py)."""
        return self.pedm / env_id / method / seed_name(seed)

    @property
    def pedm(self) -> Path:
        """Every run's PEDM-protocol folder, and the budget files that set PEDM's epochs (read by `pedm_protocol`)."""
        return self.results / "pedm"

    def sequence_scores_dir(self, env_id: str, method: str, seed: int) -> Path:
        """A MuJoCo run's sequence-detector metrics on its own dataset (paper_lib/pipeline/sequence_stage.py)."""
        return self.results / "sequence_scores" / env_id / method / seed_name(seed)

    @property
    def pedm_budget_curve(self) -> Path:
        """PEDM's validation curve per epoch on one run (paper_lib/experiments/pedm_budget.py), which set its epochs."""
        return self.pedm / "budget_curve.csv"

    def stage_paths(self, stage: str, run: Run | None = None) -> StagePaths:
        """The paths under results/ dvc.yaml's `stage` names; `run` for a per-run stage (RUN_STAGES, COMMON_STAGE,
        PEDM_STAGE, SEQUENCE_STAGE)."""
        if stage == SEQUENCE_STAGE:
            if run is None or not sequence_runs([run]):
                raise ValueError(f"stage {stage!r} is per MuJoCo run: give one, e.g. ('HalfCheetah-v5', 'baseline', 0)")
            return StagePaths(deps=(self.dataset_path(*run),), outs=(self.sequence_scores_dir(*run),))
        if stage == PEDM_STAGE:
            if run is None or not pedm_runs([run]):
                raise ValueError(f"stage {stage!r} is per MuJoCo run: give one, e.g. ('HalfCheetah-v5', 'baseline', 0)")
            # the dataset: PEDM also scores Table 2's states (pedm_stage.TABLE2_FILES)
            return StagePaths(deps=(self.checkpoint_dir(*run), self.dataset_path(*run)), outs=(self.pedm_dir(*run),))
        if stage == COMMON_STAGE:
            if run is None or run not in common_runs([run, (run[0], COMMON_STATES_OF, run[2])]):
                raise ValueError(f"stage {stage!r} is per member run: give one, e.g. (env, 'masksembles', 0)")
            return StagePaths(deps=(self.checkpoint_dir(*run), self.dataset_path(run[0], COMMON_STATES_OF, run[2])),
                              outs=(self.common_scores_dir(*run),))
        if stage in RUN_STAGES:
            if run is None:
                raise ValueError(f"stage {stage!r} is per run: give the run")
            checkpoint = (self.checkpoint_dir(*run),)
            return {"train": StagePaths(outs=checkpoint, command=(self.train_notebook(*run),)),
                    "collect": StagePaths(deps=checkpoint, outs=(self.dataset_path(*run),)),
                    "evaluate": StagePaths(deps=checkpoint, outs=(self.evaluation_path(*run),)),
                    "score": StagePaths(deps=(*checkpoint, self.dataset_path(*run)), outs=(self.scores_dir(*run),)),
                    }[stage]
        if run is not None:
            raise ValueError(f"stage {stage!r} is not per run")
        stages = self._stages()
        if stage not in stages:
            raise ValueError(f"unknown stage {stage!r}; dvc.yaml's are {list(RUN_STAGES) + list(stages)}")
        return stages[stage]

    def stage_names(self) -> tuple[str, ...]:
        """Every stage of dvc.yaml: the per-run ones (RUN_STAGES), then the others."""
        return (*RUN_STAGES, *self._stages())

    def _stages(self) -> dict[str, StagePaths]:
        """dvc.yaml's stages that are not per run: what each reads and writes under results/."""
        checkpoints, datasets, evaluations, scores = (self.folder(artifact) for artifact in RUN_FOLDERS)
        quickstart = self.checkpoint_dir(*QUICKSTART_RUN)
        parts = [self.part(name) for name in ENSEMBLE_PARTS]
        deps = {
            "rewards": (evaluations,),
            "ood": (scores, evaluations),
            "uncertainty_over_time": (scores,),
            "training_and_perturbations": (checkpoints, scores),
            # also tables/spawn_uncertainty.csv where `spawn` wrote it (not a dep: a profile may have none)
            "paper_vs_us": tuple(self.table(stem, "csv") for stem in PAPER_VS_US_READS),
            "record_example_states": (),
            "record_quickstart": (quickstart,),
            "example_states": (self.recording("example_states"),),
            "quickstart": (self.recording("quickstart"), quickstart),
            "guard": (checkpoints,),
            "spawn": (checkpoints,),
            "value_level": (checkpoints, datasets),
            "study_sweep": (),
            "study": (self.studies_db,),
            "scaling_train": (),
            "scaling": (self.scaling,),
            "ensembles_train": (),
            "ensembles_scores": tuple(part.folder("checkpoint") for part in parts),
            "ensembles": (*(part.results for part in parts), scores),
            "pedm_protocol": (self.pedm,),
        }
        writes = {  # besides the stage's tables, figures and executed notebook
            "rewards": (self.reward_episodes,),
            "pedm_protocol": (self.pedm_protocol_runs,),
            "record_example_states": (self.recording("example_states"),),
            "record_quickstart": (self.recording("quickstart"),),
            "guard": (self.guards,),
            "spawn": (self.spawn,),
            "value_level": (self.value_level,),
            "study_sweep": (self.studies_db,),
            "scaling_train": (self.scaling,),
            "ensembles_train": tuple(part.folder("checkpoint") for part in parts),
            "ensembles_scores": tuple(part.folder(kind) for part in parts for kind in ("dataset", "evaluation", "scores")),
        }
        command = {stage: (self.notebook(stage),) for stage in NOTEBOOKS}
        # the quickstart notebook's parameters: its agent, its recording, the folder of its figures
        command["quickstart"] += (quickstart, self.recording("quickstart"), self.figure_folder("quickstart"))
        return {stage: StagePaths(deps=stage_deps, outs=(*writes.get(stage, ()), *self._notebook_outputs(stage)),
                                  command=command.get(stage, ()))
                for stage, stage_deps in deps.items()}

    def _notebook_outputs(self, stage: str) -> tuple[Path, ...]:
        """A stage's tables, figures and folders of either, and its executed notebook."""
        outs = [path for stem in STAGE_TABLES.get(stage, ()) for path in self.table_files(stem)]
        outs += [path for stem in STAGE_FIGURES.get(stage, ()) for path in self.figure_files(stem)]
        outs += [self.tables / name for name in STAGE_TABLE_FOLDERS.get(stage, ())]
        outs += [self.figures / name for name in STAGE_FIGURE_FOLDERS.get(stage, ())]
        return (*outs, self.notebook(stage)) if stage in NOTEBOOKS else tuple(outs)


def _known_stem(stem: str, known: frozenset[str], kind: str, where: str) -> str:
    """`stem`, once a stage is known to write it: a notebook cannot write a table or figure dvc.yaml does not list."""
    if stem not in known:
        raise ValueError(f"unknown {kind} {stem!r}: name it in {where} (paper_lib/pipeline/layout.py) and in its "
                         "stage's outs in dvc.yaml")
    return stem


def _with_format(path: Path, fmt: str | None, formats: tuple[str, ...]) -> Path:
    """`path` (a table's or figure's stem), or its file in format `fmt`."""
    if fmt is None:
        return path
    if fmt not in formats:
        raise ValueError(f"unknown format {fmt!r} of {path.name}; use one of {list(formats)}")
    return path.with_name(f"{path.name}.{fmt}")


def _only_folder(folders: dict[str, tuple[str, ...]], stage: str, under: str) -> str:
    """The one folder under tables/ or figures/ (`under`) that `stage` writes whole."""
    names = folders.get(stage, ())
    if len(names) != 1:
        raise ValueError(f"stage {stage!r} writes {len(names)} folders under {under}/, not one; stages with one: "
                         f"{sorted(s for s, n in folders.items() if len(n) == 1)}")
    return names[0]
