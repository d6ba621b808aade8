"""StateDataset: ID and OOD states with where each came from, in one file per collection.

The OOD benchmark compares uncertainty scores of ID states (label 0) and OOD states
(label 1). Keeping each state's origin (source, configuration, episode, step) beside
it lets an analysis split results by perturbation kind or drop early-episode states
without re-running any rollout, and the metadata (env, action mode, seeds, protocol)
says how the file was made.

``states`` are raw env observations (before any VecNormalize), so detectors and
plots see physical quantities; ``policy_obs`` holds what the policy saw when the
agent was trained with VecNormalize (Walker2d), so scores use the policy's input.
``source_indicator`` (Atari) holds, per state, the value of the OOD source's indicator
(e.g. Berzerk's room counter, RAM 92) while the state was played, so the ID rollouts can
be checked never to have reached the OOD states (``paper_lib.ood.coverage``).

Files: frame stacks (Atari) are stored as their frame sequence, lzma-compressed
(``frame_store``, format 2, bit-identical on load); other states as they are (format 1).
Both formats load.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from paper_lib.common.io import remove_stale_temps, save_npz_atomic
from paper_lib.ood import frame_store

FORMAT = "paper_lib.StateDataset/1"  # states stored as they are
FORMAT_FRAMES = "paper_lib.StateDataset/2"  # frame stacks stored as their lzma-compressed frame sequence
ID_LABEL, OOD_LABEL = 0, 1
#: The source of every ID state (the agent in the unmodified env, `collect.collect_id_states`). Every OOD state names
#: what made it OOD instead ("gravity+wind", "level", "pixels:black", "noise", "atari_head"), so a label that
#: disagrees with its source is a mix-up, caught by `check_labels`.
ID_SOURCE = "id"
NO_CONFIG = -1  # config_index of a state collected in the unmodified env
NOT_RECORDED = -1  # source_indicator of a state whose collection did not read one
#: Keys of a configuration's JSON that seed the env's start, not the condition: the MuJoCo and Atari generators
#: draw one with each configuration, so the same maze or physics values drawn twice differ only there.
ENV_SEED_KEYS = ("seed",)


def condition_key(config_json: str) -> str:
    """The OOD condition a configuration JSON stands for: its parameters without the env seed (sorted JSON).

    Two configurations with the same parameters (MsPacman's maze 2 drawn twice, with other env
    seeds) are one condition: their states are no independent evidence, so the cluster bootstrap
    must resample them together and a count of conditions must count them once.
    """
    data = json.loads(config_json)
    if isinstance(data, dict):
        data = {k: v for k, v in data.items() if k not in ENV_SEED_KEYS}
    return json.dumps(data, sort_keys=True)


def _json_normalized(obj: Any, what: str) -> Any:
    """``obj`` as it reads back from JSON (tuples become lists), so save/load is exact."""
    try:
        return json.loads(json.dumps(obj, sort_keys=True))
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what} must be JSON-serializable (plain dicts, lists, str, numbers): {err}") from err


@dataclass(eq=False)
class StateDataset:
    """N states with labels and provenance; every per-state array has length N.

    ``config_index[i]`` indexes ``configs`` (JSON strings of the OOD configuration the
    state was collected in), or is -1 for states of the unmodified env.
    """

    states: np.ndarray  # (N, *obs_shape) raw env observations
    labels: np.ndarray  # (N,) 0 = ID, 1 = OOD
    source: np.ndarray  # (N,) str: "id", "gravity+friction", "pixels:black", ...
    config_index: np.ndarray  # (N,) int, -1 = no configuration
    episode: np.ndarray  # (N,) int, episode number within the collection (episodes that kept states)
    step: np.ndarray  # (N,) int, step within that episode (0 = the reset observation)
    configs: list[str] = field(default_factory=list)
    metadata: dict[str, Any] = field(default_factory=dict)
    policy_obs: np.ndarray | None = None  # (N, *obs_shape) normalized obs, only with VecNormalize
    source_indicator: np.ndarray | None = None  # (N,) int, the OOD source's indicator (Atari); -1 = not read

    def __post_init__(self) -> None:
        self.states = np.asarray(self.states)
        if self.states.ndim < 2:
            raise ValueError(f"states must have shape (N, *obs_shape), got {self.states.shape}; "
                             "for one state use states[None].")
        n = len(self.states)
        self.labels = np.asarray(self.labels, dtype=np.int8)
        self.source = np.asarray(self.source, dtype=str)
        self.config_index = np.asarray(self.config_index, dtype=np.int64)
        self.episode = np.asarray(self.episode, dtype=np.int64)
        self.step = np.asarray(self.step, dtype=np.int64)
        for name in ("labels", "source", "config_index", "episode", "step"):
            arr = getattr(self, name)
            if arr.shape != (n,):
                raise ValueError(f"{name} has shape {arr.shape} but there are {n} states: give one entry per state.")
        if not np.isin(self.labels, (ID_LABEL, OOD_LABEL)).all():
            raise ValueError(f"labels must be 0 (ID) or 1 (OOD), got values {np.unique(self.labels).tolist()}.")
        self.configs = [str(c) for c in self.configs]
        bad = (self.config_index < NO_CONFIG) | (self.config_index >= len(self.configs))
        if bad.any():
            raise ValueError(f"config_index holds {self.config_index[bad][:5].tolist()}, outside "
                             f"[-1, {len(self.configs) - 1}]: each must index configs or be -1.")
        self.metadata = _json_normalized(dict(self.metadata), "metadata")
        if self.policy_obs is not None:
            self.policy_obs = np.asarray(self.policy_obs)
            if len(self.policy_obs) != n:
                raise ValueError(f"policy_obs has {len(self.policy_obs)} rows but there are {n} states.")
        if self.source_indicator is not None:
            self.source_indicator = _indicator_array(self.source_indicator, n)

    def __len__(self) -> int:
        return len(self.states)

    def __repr__(self) -> str:
        n_ood = int(self.labels.sum())
        return (f"StateDataset({len(self)} states {self.states.shape[1:]} {self.states.dtype}: "
                f"{len(self) - n_ood} ID, {n_ood} OOD, {self.n_conditions} distinct OOD conditions, "
                f"sources {sorted(set(self.source.tolist()))})")

    def config_json(self, i: int) -> str | None:
        """The JSON configuration state ``i`` was collected in, None for the unmodified env."""
        k = int(self.config_index[i])
        return None if k == NO_CONFIG else self.configs[k]

    def condition_index(self) -> np.ndarray:
        """(N,) int: per state, its configuration's condition (``condition_key``), -1 for the unmodified env.

        Configurations with the same parameters share one number (numbered in order of first
        appearance in ``configs``), so these are the OOD clusters of the bootstrap.
        """
        numbers: dict[str, int] = {}
        of_config = np.array([numbers.setdefault(condition_key(c), len(numbers)) for c in self.configs] + [NO_CONFIG],
                             dtype=np.int64)
        return of_config[self.config_index]  # config_index -1 picks the trailing NO_CONFIG

    @property
    def n_conditions(self) -> int:
        """How many distinct OOD conditions the states come from (identical configurations count once)."""
        index = self.condition_index()
        return int(np.unique(index[index != NO_CONFIG]).size)

    def equals(self, other: StateDataset) -> bool:
        """Exact equality of every array, config and metadata entry."""
        arrays = ("states", "labels", "source", "config_index", "episode", "step")
        same = all(np.array_equal(getattr(self, a), getattr(other, a)) for a in arrays)
        same &= self.states.dtype == other.states.dtype
        same &= (self.policy_obs is None) == (other.policy_obs is None)
        if self.policy_obs is not None and other.policy_obs is not None:
            same &= np.array_equal(self.policy_obs, other.policy_obs)
        same &= (self.source_indicator is None) == (other.source_indicator is None)
        if self.source_indicator is not None and other.source_indicator is not None:
            same &= np.array_equal(self.source_indicator, other.source_indicator)
        return bool(same and self.configs == other.configs and self.metadata == other.metadata)

    # --------------------------------------------------------------- selection
    def subset(self, mask: np.ndarray) -> StateDataset:
        """The states where ``mask`` (boolean of length N, or integer indices) selects them.

        ``configs`` is kept whole so config indices stay valid.
        """
        mask = np.asarray(mask)
        if mask.size == 0:
            mask = mask.astype(np.int64)  # np.asarray([]) is float: select nothing
        if mask.dtype == bool and mask.shape != (len(self),):
            raise ValueError(f"boolean mask has shape {mask.shape}; need ({len(self)},), one entry per state.")
        if mask.dtype != bool and not np.issubdtype(mask.dtype, np.integer) and mask.size > 0:
            raise ValueError(f"mask must be boolean or integer indices, got dtype {mask.dtype}.")
        return StateDataset(
            states=self.states[mask], labels=self.labels[mask], source=self.source[mask],
            config_index=self.config_index[mask], episode=self.episode[mask], step=self.step[mask],
            configs=list(self.configs), metadata=dict(self.metadata),
            policy_obs=None if self.policy_obs is None else self.policy_obs[mask],
            source_indicator=None if self.source_indicator is None else self.source_indicator[mask],
        )

    def id_only(self) -> StateDataset:
        return self.subset(self.labels == ID_LABEL)

    def ood_only(self) -> StateDataset:
        return self.subset(self.labels == OOD_LABEL)

    # --------------------------------------------------------------------- I/O
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write one compressed ``.npz`` (atomic); configs and metadata go in as JSON text.

        Frame stacks go in as their frame sequence (format 2: 10-30x smaller, exact on load).
        """
        arrays: dict[str, np.ndarray] = dict(
            format=np.array(FORMAT), states=self.states, labels=self.labels, source=self.source,
            config_index=self.config_index, episode=self.episode, step=self.step,
            configs=np.array(json.dumps(self.configs)), metadata=np.array(json.dumps(self.metadata, sort_keys=True)),
        )
        if frame_store.is_frame_stacks(self.states):
            del arrays["states"]
            frames, new_stack = frame_store.to_frames(self.states)
            arrays.update(format=np.array(FORMAT_FRAMES), frames_xz=frame_store.pack(frames), new_stack=new_stack,
                          state_shape=np.array(self.states.shape[1:], dtype=np.int64))
        if self.policy_obs is not None:
            arrays["policy_obs"] = self.policy_obs
        if self.source_indicator is not None:
            arrays["source_indicator"] = self.source_indicator
        remove_stale_temps(path)  # temp files of a writer killed before its rename
        return save_npz_atomic(path, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike[str], remedy: str = "run the collection that writes it again") -> StateDataset:
        """Read a file written by ``save`` (either format); a missing or damaged file raises a clear error ending in
        ``remedy`` (the pipeline names its stage command there)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"No StateDataset at {path}: {remedy}, or check the path.")
        try:
            with np.load(path, allow_pickle=False) as f:
                fmt = str(f["format"]) if "format" in f.files else None
                if fmt not in (FORMAT, FORMAT_FRAMES):
                    raise ValueError(f"it has no '{FORMAT}' or '{FORMAT_FRAMES}' format tag")
                data = {k: f[k] for k in f.files}
            dataset = cls(
                states=_stored_states(data, fmt), labels=data["labels"], source=data["source"],
                config_index=data["config_index"], episode=data["episode"], step=data["step"],
                configs=json.loads(str(data["configs"])), metadata=json.loads(str(data["metadata"])),
                policy_obs=data.get("policy_obs"), source_indicator=data.get("source_indicator"),
            )
        except Exception as err:  # zip, npy, lzma, JSON and field errors all mean one thing here
            raise ValueError(f"{path} is not a readable StateDataset ({type(err).__name__}: {err}); the file is "
                             f"damaged or was written by something else: {remedy}.") from err
        check_labels(dataset, str(path))
        return dataset


def label_contradictions(dataset: StateDataset) -> np.ndarray:
    """Boolean mask of the states whose label contradicts their source: labelled ID but of an OOD source, or labelled
    OOD but of source `ID_SOURCE`."""
    return (dataset.labels == ID_LABEL) != (dataset.source == ID_SOURCE)


def check_labels(dataset: StateDataset, where: str = "the dataset") -> None:
    """Refuse a dataset whose labels contradict their sources, or whose ID states name an OOD configuration: scored,
    its OOD states would count as ID (or the reverse) and every AUROC would be wrong without any error. `where` names
    the file in the message."""
    wrong = np.flatnonzero(label_contradictions(dataset))
    if wrong.size:
        i = int(wrong[0])
        label = "ID" if dataset.labels[i] == ID_LABEL else "OOD"
        raise ValueError(f"{where}: {wrong.size} of {len(dataset)} states have a label that contradicts their source "
                         f"(e.g. state {i}: source {str(dataset.source[i])!r} labelled {label}); ID states, and only "
                         f"they, come from source {ID_SOURCE!r}: collect the states again (`make recollect`) or "
                         "correct the labels")
    configured = np.flatnonzero((dataset.source == ID_SOURCE) & (dataset.config_index != NO_CONFIG))
    if configured.size:  # OOD states relabelled as ID (label and source both changed) still name their configuration
        i = int(configured[0])
        raise ValueError(f"{where}: {configured.size} of {len(dataset)} states of source {ID_SOURCE!r} point at an OOD "
                         f"configuration (e.g. state {i}: config_index {int(dataset.config_index[i])}); ID states are "
                         f"collected in the unmodified env (config_index {NO_CONFIG}), so these are relabelled OOD "
                         "states: collect the states again (`make recollect`) or correct the labels")


def _stored_states(data: dict[str, np.ndarray], fmt: str) -> np.ndarray:
    """The states of a loaded file, rebuilt from the frame store in format 2."""
    if fmt == FORMAT:
        return data["states"]
    shape = tuple(int(v) for v in data["state_shape"])
    if len(shape) != 3:
        raise ValueError(f"state_shape {shape} is not (H, W, k)")
    frames = frame_store.unpack(data["frames_xz"], shape[:2])
    return frame_store.from_frames(frames, data["new_stack"], shape[2])


def _indicator_array(values: np.ndarray, n: int) -> np.ndarray:
    """``values`` as an (n,) int16 array of indicator values (0-255 RAM bytes, modes) or NOT_RECORDED."""
    arr = np.asarray(values)
    if arr.shape != (n,) or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"source_indicator has shape {arr.shape} and dtype {arr.dtype}; give one int per state "
                         f"({n}), {NOT_RECORDED} where none was read.")
    if arr.size and (arr.min() < NOT_RECORDED or arr.max() > np.iinfo(np.int16).max):
        raise ValueError(f"source_indicator holds values in [{arr.min()}, {arr.max()}]: indicators are RAM bytes or "
                         f"ALE modes (>= 0), or {NOT_RECORDED} where none was read.")
    return arr.astype(np.int16)


def concat(a: StateDataset, b: StateDataset) -> StateDataset:
    """One dataset holding ``a``'s states then ``b``'s (e.g. ID + OOD for scoring).

    Both must come from the same env, agent and action mode, or the comparison is not fair.
    ``b``'s config indices are remapped into the merged ``configs`` list (identical
    configurations share one entry). Metadata entries equal in both are kept at the
    top level; both originals are kept under ``"parts"``.
    """
    if not (isinstance(a, StateDataset) and isinstance(b, StateDataset)):
        raise TypeError(f"concat needs two StateDatasets, got {type(a).__name__} and {type(b).__name__}.")
    for key in ("env_id", "model", "action_mode"):
        if key in a.metadata and key in b.metadata and a.metadata[key] != b.metadata[key]:
            raise ValueError(f"cannot concat datasets with different {key}: {a.metadata[key]!r} vs "
                             f"{b.metadata[key]!r}; collect ID and OOD states with the same {key}.")
    if a.states.shape[1:] != b.states.shape[1:] or a.states.dtype != b.states.dtype:
        raise ValueError(f"state shapes differ: {a.states.shape[1:]} {a.states.dtype} vs "
                         f"{b.states.shape[1:]} {b.states.dtype}.")
    if (a.policy_obs is None) != (b.policy_obs is None):
        raise ValueError("one dataset has policy_obs (collected with VecNormalize) and the other has not: "
                         "collect both with the same vecnormalize.")
    configs = list(a.configs)
    position = {c: i for i, c in enumerate(configs)}
    remap = np.empty(len(b.configs), dtype=np.int64)
    for i, c in enumerate(b.configs):
        if c not in position:
            position[c] = len(configs)
            configs.append(c)
        remap[i] = position[c]
    b_index = b.config_index.copy()
    has_config = b_index != NO_CONFIG
    b_index[has_config] = remap[b_index[has_config]]
    metadata = {k: v for k, v in a.metadata.items() if k != "parts" and b.metadata.get(k) == v}
    metadata["parts"] = a.metadata.get("parts", [a.metadata]) + b.metadata.get("parts", [b.metadata])
    return StateDataset(
        states=np.concatenate([a.states, b.states]), labels=np.concatenate([a.labels, b.labels]),
        source=np.concatenate([a.source, b.source]), config_index=np.concatenate([a.config_index, b_index]),
        episode=np.concatenate([a.episode, b.episode]), step=np.concatenate([a.step, b.step]),
        configs=configs, metadata=metadata,
        policy_obs=None if a.policy_obs is None else np.concatenate([a.policy_obs, b.policy_obs]),
        source_indicator=_concat_indicators(a, b),
    )


def _concat_indicators(a: StateDataset, b: StateDataset) -> np.ndarray | None:
    """Both parts' indicators, NOT_RECORDED for the states of a part that has none; None if neither has."""
    if a.source_indicator is None and b.source_indicator is None:
        return None
    parts = [d.source_indicator if d.source_indicator is not None else np.full(len(d), NOT_RECORDED, np.int16)
             for d in (a, b)]
    return np.concatenate(parts)
