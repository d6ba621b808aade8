"""Load OOD states from a local copy of Atari-HEAD (human play), preprocessed like the agent's input.

The paper's Atari OOD states are Atari-HEAD frames from advanced levels. The data set
cannot be downloaded here, so this loader reads a local copy in its published layout:

    <root>/<game>/meta_data.csv
    <root>/<game>/<trial>.tar.bz2   PNG frames, 210x160 RGB, named <frame_id>.png
    <root>/<game>/<trial>.txt       frame_id,episode_id,score,duration(ms),unclipped_reward,action,gaze_positions

The frames are raw emulator frames. The agent saw them through SB3's AtariWrapper and
VecFrameStack, so the loader redoes that: one state per ``frame_skip`` frames, the
pixel-wise max of the last two frames of each skip (MaxAndSkipEnv), grey and 84x84
INTER_AREA (WarpFrame), 4 of them stacked oldest first (VecFrameStack).

``atari_head_ood_dataset`` makes them a run's OOD set; the pipeline uses it in place of the
edited game states when params.yaml sets ``atari_head.root`` (``paper_lib.pipeline.stages.collect_states``).
"""

from __future__ import annotations

import json
import tarfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import cv2
import numpy as np

from paper_lib.ood.atari import game_of
from paper_lib.ood.datasets import OOD_LABEL, StateDataset

LABEL_HEADER: tuple[str, ...] = (
    "frame_id", "episode_id", "score", "duration(ms)", "unclipped_reward", "action", "gaze_positions",
)
FRAME_SHAPE = (210, 160, 3)
N_STACK = 4
SCREEN_SIZE = 84
# Atari-HEAD names its game folders in snake case.
_FOLDER_NAMES = {"Seaquest": "seaquest", "MsPacman": "ms_pacman", "Berzerk": "berzerk",
                 "SpaceInvaders": "space_invaders"}


@dataclass(frozen=True)
class FrameLabel:
    """One row of a trial's label file; ``episode_id`` and ``score`` may be null (None)."""

    frame_id: str
    episode_id: str | None
    score: int | None
    action: int | None
    gaze: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class StateInfo:
    """Where a loaded state comes from: the raw frames behind its 4 stacked images, oldest first."""

    trial: str
    episode_id: str | None
    frame_ids: tuple[str, ...]
    score: int | None  # score at the newest frame
    step: int  # the agent step within its episode (0 = the episode's first frame_skip frames)


def _null(text: str) -> str | None:
    text = text.strip()
    return None if text in ("", "null", "None", "NaN", "nan") else text


def _int_or_none(text: str) -> int | None:
    value = _null(text)
    return None if value is None else int(float(value))


def read_labels(path: str | Path) -> list[FrameLabel]:
    """Parse a trial's label file (a header row, then one row per frame)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"Atari-HEAD label file {path} does not exist: each <trial>.tar.bz2 needs "
                                f"a <trial>.txt beside it.")
    try:
        lines = path.read_text().splitlines()
    except UnicodeDecodeError as err:
        raise ValueError(f"Atari-HEAD label file {path} is not a text file ({err}); copy it again.") from None
    header = tuple(h.strip() for h in lines[0].split(",")) if lines else ()
    if header != LABEL_HEADER:
        raise ValueError(f"Malformed header in {path}: got {list(header)}, expected {list(LABEL_HEADER)}.")
    labels = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = line.split(",")
        if len(cells) < len(LABEL_HEADER) - 1:
            raise ValueError(f"{path}, line {number}: {len(cells)} fields, need at least {len(LABEL_HEADER) - 1}.")
        try:
            gaze_cells = [c for c in cells[6:] if _null(c) is not None]
            if len(gaze_cells) % 2:
                raise ValueError("odd number of gaze coordinates")
            gaze = tuple(zip(map(float, gaze_cells[0::2]), map(float, gaze_cells[1::2])))
            labels.append(FrameLabel(cells[0].strip(), _null(cells[1]), _int_or_none(cells[2]),
                                     _int_or_none(cells[5]), gaze))
        except ValueError as err:
            raise ValueError(f"{path}, line {number}: cannot parse {line!r} ({err}).") from None
    return labels


def game_folder(root: str | Path, game: str) -> Path:
    """The folder of ``game`` under ``root`` ("MsPacman" is found as ms_pacman, mspacman or MsPacman)."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"Atari-HEAD root {root} does not exist: pass the folder that holds the "
                                f"per-game folders of your local copy.")
    names = [game, _FOLDER_NAMES.get(game, game), game.lower()]
    for name in dict.fromkeys(names):
        if (root / name).is_dir():
            return root / name
    present = sorted(p.name for p in root.iterdir() if p.is_dir())
    raise FileNotFoundError(f"No folder for {game!r} in {root} (tried {list(dict.fromkeys(names))}; "
                            f"found {present}).")


def list_trials(root: str | Path, game: str) -> list[str]:
    """Trial names (archive file names without .tar.bz2) of a game folder, sorted."""
    folder = game_folder(root, game)
    trials = sorted(p.name[: -len(".tar.bz2")] for p in folder.glob("*.tar.bz2"))
    if not trials:
        raise FileNotFoundError(f"No <trial>.tar.bz2 archives in {folder}.")
    for trial in trials:
        if not (folder / f"{trial}.txt").is_file():
            raise FileNotFoundError(f"Label file {folder / (trial + '.txt')} is missing for archive "
                                    f"{trial}.tar.bz2: copy both files of each trial.")
    return trials


def warp_frame(rgb: np.ndarray) -> np.ndarray:
    """Grey 84x84 image of an RGB frame, computed as SB3's WarpFrame does."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return cv2.resize(grey, (SCREEN_SIZE, SCREEN_SIZE), interpolation=cv2.INTER_AREA)


def _segments(labels: list[FrameLabel]) -> list[tuple[int, int]]:
    """[start, end) row ranges of consecutive frames with the same episode id: stacks stay inside one."""
    bounds, start = [], 0
    for i in range(1, len(labels) + 1):
        if i == len(labels) or labels[i].episode_id != labels[start].episode_id:
            bounds.append((start, i))
            start = i
    return bounds


def _state_rows(start: int, step: int, frame_skip: int) -> list[list[int]]:
    """Rows of the raw frames behind the 4 stacked images of agent step ``step``, oldest first."""
    pooled = 2 if frame_skip > 1 else 1
    return [[start + (s + 1) * frame_skip - 1 - k for k in reversed(range(pooled))]
            for s in range(step - N_STACK + 1, step + 1)]


def _read_frames(archive: Path, wanted: set[str]) -> dict[str, np.ndarray]:
    """RGB frames of ``archive`` whose file stem is in ``wanted`` (one pass over the bz2 stream)."""
    frames: dict[str, np.ndarray] = {}
    try:
        with tarfile.open(archive, "r:bz2") as tar:
            for member in tar:
                stem = PurePosixPath(member.name).stem
                if not member.isfile() or stem not in wanted or not member.name.endswith(".png"):
                    continue
                data = tar.extractfile(member).read()
                bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                if bgr is None or bgr.shape != FRAME_SHAPE:
                    got = None if bgr is None else bgr.shape
                    raise ValueError(f"{archive}:{member.name} is not a {FRAME_SHAPE} RGB PNG (got {got}).")
                frames[stem] = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    except (tarfile.TarError, EOFError, OSError) as err:  # truncated download, not bzip2, not a tar
        raise ValueError(f"Atari-HEAD archive {archive} is corrupt or not a .tar.bz2 ({type(err).__name__}: {err}); "
                         f"copy it again from the data set.") from None
    missing = sorted(wanted - set(frames))
    if missing:
        raise ValueError(f"{len(missing)} frames of the label file are missing from {archive}, e.g. "
                         f"{missing[:3]}: the archive is incomplete or does not match its label file.")
    return frames


def load_atari_head_states(root: str | Path, game: str, n_states: int, rng: np.random.Generator,
                           frame_skip: int = 4) -> tuple[np.ndarray, list[StateInfo]]:
    """Sample ``n_states`` stacked states (N, 84, 84, 4) uint8 from the human play of ``game``.

    States are drawn uniformly without replacement over all trials and all agent steps
    that have 4 full stacked images inside one episode (rows with the same episode id).
    Returns the states, in the drawn order, and per state its trial, raw frame ids and step.
    ``frame_skip=1`` takes every row as one agent step, without max-pooling.
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")
    if isinstance(n_states, bool) or not isinstance(n_states, (int, np.integer)) or n_states < 1:
        raise ValueError(f"n_states={n_states!r}: need a positive int.")
    if isinstance(frame_skip, bool) or not isinstance(frame_skip, (int, np.integer)) or frame_skip < 1:
        raise ValueError(f"frame_skip={frame_skip!r}: need a positive int (the agent's is 4).")
    folder = game_folder(root, game)
    trials = list_trials(root, game)
    labels = {trial: read_labels(folder / f"{trial}.txt") for trial in trials}
    candidates = [(trial, start, step)
                  for trial in trials for start, end in _segments(labels[trial])
                  for step in range(N_STACK - 1, (end - start) // frame_skip)]
    if n_states > len(candidates):
        raise ValueError(f"n_states={n_states} but {folder} holds only {len(candidates)} full stacked states "
                         f"at frame_skip={frame_skip}.")
    picks = [candidates[i] for i in rng.choice(len(candidates), size=n_states, replace=False)]
    states = np.empty((n_states, SCREEN_SIZE, SCREEN_SIZE, N_STACK), dtype=np.uint8)
    infos: list[StateInfo | None] = [None] * n_states
    order = {pick: i for i, pick in enumerate(picks)}  # results keep the drawn order
    for trial in trials:
        mine = [p for p in picks if p[0] == trial]
        if not mine:
            continue
        rows = {p: _state_rows(p[1], p[2], frame_skip) for p in mine}
        ids = labels[trial]
        frames = _read_frames(folder / f"{trial}.tar.bz2",
                              {ids[r].frame_id for stack in rows.values() for pair in stack for r in pair})
        for pick, stack in rows.items():
            i = order[pick]
            for c, pair in enumerate(stack):
                # MaxAndSkipEnv pools the RGB frames, then WarpFrame converts.
                states[i, :, :, c] = warp_frame(np.max([frames[ids[r].frame_id] for r in pair], axis=0))
            newest = ids[stack[-1][-1]]
            infos[i] = StateInfo(trial, newest.episode_id,
                                 tuple(ids[r].frame_id for pair in stack for r in pair), newest.score, pick[2])
    return states, [info for info in infos if info is not None]


#: The ``source`` of Atari-HEAD states in a StateDataset, and the ``kind`` and protocol name in its metadata.
HEAD_SOURCE = "atari_head"
HEAD_KIND = "atari_head_ood"


def atari_head_ood_dataset(root: str | Path, env_id: str, n_states: int, seed: int,
                           frame_skip: int = 4) -> StateDataset:
    """The OOD set of an ``env_id`` agent from human play (the paper's source), as a StateDataset.

    ``n_states`` states drawn with ``np.random.default_rng(seed)``, kept in play order (trial,
    episode, step: the over-time plots then show human play as it went); each human trial is one
    configuration (so the cluster bootstrap resamples whole trials), each (trial, episode) one
    episode. The metadata names the game and trials, not ``root``: the same copy gives the same
    dataset on any machine.
    """
    game = game_of(env_id)
    states, infos = load_atari_head_states(root, game, n_states, np.random.default_rng(seed), frame_skip)
    order = sorted(range(len(infos)), key=lambda i: (infos[i].trial, str(infos[i].episode_id), infos[i].step))
    states, infos = states[order], [infos[i] for i in order]  # play order, as the agent's own collections
    trials = sorted({info.trial for info in infos})
    configs = [json.dumps({"source": HEAD_SOURCE, "game": game, "trial": t}, sort_keys=True) for t in trials]
    episodes = {key: i for i, key in enumerate(sorted({(info.trial, str(info.episode_id)) for info in infos}))}
    metadata = {"kind": HEAD_KIND, "env_id": env_id, "game": game, "seed": int(seed), "frame_skip": int(frame_skip),
                "protocol": {"name": HEAD_SOURCE, "n_states": int(n_states)}, "trials": trials}
    return StateDataset(states=states, labels=np.full(len(states), OOD_LABEL), source=[HEAD_SOURCE] * len(states),
                        config_index=[trials.index(info.trial) for info in infos],
                        episode=[episodes[(info.trial, str(info.episode_id))] for info in infos],
                        step=[info.step for info in infos], configs=configs, metadata=metadata)
