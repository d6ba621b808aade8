"""Atari-HEAD loader on a tiny fixture in the published format, checked against SB3's own wrappers."""

from __future__ import annotations

import dataclasses
import json
import tarfile
from pathlib import Path

import cv2
import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.atari_wrappers import MaxAndSkipEnv, WarpFrame
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from conftest import TINY
from paper_lib import make_agent
from paper_lib.pipeline.config import load_run_config
from paper_lib.ood.atari_head import (
    HEAD_SOURCE,
    LABEL_HEADER,
    atari_head_ood_dataset,
    list_trials,
    load_atari_head_states,
    read_labels,
    warp_frame,
)
from paper_lib.ood.coverage import HUMAN_PLAY, source_coverage
from paper_lib.ood.datasets import StateDataset
from paper_lib.pipeline.run_results import collection_actions, collection_protocol
from paper_lib.pipeline.stages import collect_states

# trial name -> episode id of each frame (Atari-HEAD writes "null" outside episodes)
TRIALS = {
    "100_RZ_3592991_Aug-24-11-44-38": ["0"] * 40 + ["1"] * 30,
    "101_RZ_3603003_Aug-24-14-20-51": ["null"] * 3 + ["0"] * 36,
}


def frame_id(trial: str, i: int) -> str:
    return f"RZ_{trial.split('_')[2]}_{i + 1}"


def synthetic_frame(rng: np.random.Generator) -> np.ndarray:
    """An RGB frame with blocks of colour, so that resizing and max-pooling have something to do."""
    small = rng.integers(0, 256, size=(21, 16, 3), dtype=np.uint8)
    return cv2.resize(small, (160, 210), interpolation=cv2.INTER_NEAREST)


def write_trial(folder: Path, trial: str, episodes: list[str], frames: dict[str, np.ndarray],
                rng: np.random.Generator, skip: set[int] = frozenset()) -> None:
    lines = [",".join(LABEL_HEADER)]
    png_dir = folder / trial
    png_dir.mkdir()
    for i, episode in enumerate(episodes):
        fid = frame_id(trial, i)
        frames[fid] = synthetic_frame(rng)
        if i not in skip:
            cv2.imwrite(str(png_dir / f"{fid}.png"), cv2.cvtColor(frames[fid], cv2.COLOR_RGB2BGR))
        gaze = ",".join(f"{x:.2f}" for x in rng.uniform(0, 160, size=2 * int(rng.integers(0, 4)))) or "null"
        lines.append(f"{fid},{episode},{10 * i},50,0,{i % 18},{gaze}")
    with tarfile.open(folder / f"{trial}.tar.bz2", "w:bz2") as tar:
        tar.add(png_dir, arcname=trial)  # real archives hold a <trial>/ folder of PNGs
    for png in png_dir.iterdir():
        png.unlink()
    png_dir.rmdir()
    (folder / f"{trial}.txt").write_text("\n".join(lines) + "\n")


@pytest.fixture()
def head_root(tmp_path) -> tuple[Path, dict[str, np.ndarray]]:
    rng = np.random.default_rng(0)
    folder = tmp_path / "seaquest"
    folder.mkdir()
    (folder / "meta_data.csv").write_text(
        "GameName,TrialNumber,SubjectID,NumberOfFrames\n"
        + "".join(f"seaquest,{t.split('_')[0]},RZ,{len(e)}\n" for t, e in TRIALS.items()))
    frames: dict[str, np.ndarray] = {}
    for trial, episodes in TRIALS.items():
        write_trial(folder, trial, episodes, frames, rng)
    return tmp_path, frames


class ReplayEnv(gym.Env):
    """Plays a trial's frames back, so that SB3's real wrappers can preprocess them."""

    observation_space = gym.spaces.Box(0, 255, (210, 160, 3), np.uint8)
    action_space = gym.spaces.Discrete(1)

    def __init__(self, frames: list[np.ndarray]) -> None:
        self.frames, self.t = frames, 0

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros((210, 160, 3), np.uint8), {}

    def step(self, action):
        frame = self.frames[self.t]
        self.t += 1
        return frame, 0.0, False, False, {}


def sb3_states(frames: list[np.ndarray], frame_skip: int) -> list[np.ndarray]:
    """Stacked states after each agent step, computed by MaxAndSkipEnv, WarpFrame and VecFrameStack."""

    def make():
        env = ReplayEnv(frames)
        return WarpFrame(MaxAndSkipEnv(env, skip=frame_skip) if frame_skip > 1 else env)

    venv = VecFrameStack(DummyVecEnv([make]), n_stack=4)
    venv.reset()
    return [venv.step(np.zeros(1, dtype=int))[0][0] for _ in range(len(frames) // frame_skip)]


def test_labels_parse_null_and_variable_gaze(head_root):
    root, _ = head_root
    labels = read_labels(root / "seaquest" / "101_RZ_3603003_Aug-24-14-20-51.txt")
    assert len(labels) == 39 and labels[0].episode_id is None and labels[5].episode_id == "0"
    assert labels[4].score == 40 and labels[4].action == 4
    assert {len(lab.gaze) for lab in labels} <= {0, 1, 2, 3} and len({len(lab.gaze) for lab in labels}) > 1
    assert list_trials(root, "Seaquest") == sorted(TRIALS)


def test_warp_frame_is_sb3_warp_frame():
    frame = synthetic_frame(np.random.default_rng(3))
    expected = WarpFrame(ReplayEnv([frame])).observation(frame)[:, :, 0]
    np.testing.assert_array_equal(warp_frame(frame), expected)
    assert expected.shape == (84, 84) and len(np.unique(expected)) > 50


@pytest.mark.parametrize("frame_skip", [4, 1])
def test_states_equal_sb3_preprocessing(head_root, frame_skip):
    root, frames = head_root
    states, infos = load_atari_head_states(root, "Seaquest", 8, np.random.default_rng(1), frame_skip=frame_skip)
    assert states.shape == (8, 84, 84, 4) and states.dtype == np.uint8 and len(infos) == 8
    reference: dict[tuple[str, str | None], list] = {}
    for state, info in zip(states, infos):
        trial, episodes = info.trial, TRIALS[info.trial]
        rows = [i for i, e in enumerate(episodes) if (None if e == "null" else e) == info.episode_id]
        assert rows == list(range(rows[0], rows[-1] + 1)), "an episode is one run of frames"
        key = (trial, info.episode_id)
        if key not in reference:
            reference[key] = sb3_states([frames[frame_id(trial, r)] for r in rows], frame_skip)
        newest = int(info.frame_ids[-1].split("_")[-1]) - 1 - rows[0]  # row in the episode
        step = (newest + 1) // frame_skip - 1
        assert len(info.frame_ids) == 4 * min(frame_skip, 2)
        np.testing.assert_array_equal(state, reference[key][step])
        assert info.score == 10 * (newest + rows[0])


def test_sampling_is_seeded_and_stays_inside_episodes(head_root):
    root, _ = head_root
    a, infos = load_atari_head_states(root, "Seaquest", 6, np.random.default_rng(5))
    b, _ = load_atari_head_states(root, "Seaquest", 6, np.random.default_rng(5))
    np.testing.assert_array_equal(a, b)
    # Full stacks only: episodes of 40, 30, 3 and 36 frames give 7 + 4 + 0 + 6 states at skip 4.
    _, all_infos = load_atari_head_states(root, "Seaquest", 17, np.random.default_rng(0))
    assert len({info.frame_ids for info in all_infos}) == 17
    assert all(info.episode_id is not None for info in all_infos)
    with pytest.raises(ValueError, match="holds only 17 full stacked states"):
        load_atari_head_states(root, "Seaquest", 18, np.random.default_rng(0))


def test_missing_root_and_game_folder(head_root, tmp_path):
    root, _ = head_root
    with pytest.raises(FileNotFoundError, match="Atari-HEAD root .* does not exist"):
        load_atari_head_states(tmp_path / "nope", "Seaquest", 1, np.random.default_rng(0))
    with pytest.raises(FileNotFoundError, match="No folder for 'MsPacman'.*ms_pacman.*found \\['seaquest'\\]"):
        load_atari_head_states(root, "MsPacman", 1, np.random.default_rng(0))


def test_missing_label_file(head_root):
    root, _ = head_root
    (root / "seaquest" / "101_RZ_3603003_Aug-24-14-20-51.txt").unlink()
    with pytest.raises(FileNotFoundError, match="Label file .*101_RZ.*txt is missing"):
        load_atari_head_states(root, "Seaquest", 1, np.random.default_rng(0))


def test_malformed_header(head_root):
    root, _ = head_root
    path = root / "seaquest" / "100_RZ_3592991_Aug-24-11-44-38.txt"
    path.write_text(path.read_text().replace("gaze_positions", "gaze"))
    with pytest.raises(ValueError, match="Malformed header .* expected \\['frame_id'"):
        load_atari_head_states(root, "Seaquest", 1, np.random.default_rng(0))


def test_frames_missing_from_archive(tmp_path):
    folder = tmp_path / "seaquest"
    folder.mkdir()
    trial = "100_RZ_3592991_Aug-24-11-44-38"
    write_trial(folder, trial, ["0"] * 16, {}, np.random.default_rng(0), skip={14})
    with pytest.raises(ValueError, match="1 frames of the label file are missing .* \\['RZ_3592991_15'\\]"):
        load_atari_head_states(tmp_path, "Seaquest", 1, np.random.default_rng(0))


def test_bad_arguments(head_root):
    root, _ = head_root
    with pytest.raises(ValueError, match="numpy Generator"):
        load_atari_head_states(root, "Seaquest", 1, 0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="n_states=0"):
        load_atari_head_states(root, "Seaquest", 0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="frame_skip=0"):
        load_atari_head_states(root, "Seaquest", 1, np.random.default_rng(0), frame_skip=0)


@pytest.mark.parametrize("damage", ["truncated", "not bzip2"])
def test_corrupt_archive_is_named(head_root, damage):
    root, _ = head_root
    archive = root / "seaquest" / "100_RZ_3592991_Aug-24-11-44-38.tar.bz2"
    data = archive.read_bytes()
    archive.write_bytes(data[: len(data) // 2] if damage == "truncated" else b"PK\x03\x04 a zip, say")
    with pytest.raises(ValueError, match=f"Atari-HEAD archive {archive} is corrupt or not a .tar.bz2") as err:
        load_atari_head_states(root, "Seaquest", 17, np.random.default_rng(0))  # every state: both trials are read
    assert "\n" not in str(err.value)


SEAQUEST = "SeaquestNoFrameskip-v4"


def test_head_dataset_holds_the_loaders_states_with_their_provenance(head_root, tmp_path):
    root, _ = head_root
    data = atari_head_ood_dataset(root, SEAQUEST, 10, seed=3)
    states, infos = load_atari_head_states(root, "Seaquest", 10, np.random.default_rng(3))
    order = sorted(range(10), key=lambda i: (infos[i].trial, str(infos[i].episode_id), infos[i].step))
    assert order != list(range(10))  # drawn at random, kept in play order
    states, infos = states[order], [infos[i] for i in order]
    np.testing.assert_array_equal(data.states, states)
    assert (data.labels == 1).all() and set(data.source) == {HEAD_SOURCE}
    assert [json.loads(data.config_json(i))["trial"] for i in range(10)] == [info.trial for info in infos]
    assert data.step.tolist() == [info.step for info in infos]
    assert len(set(data.episode.tolist())) == len({(info.trial, info.episode_id) for info in infos}) > 1
    assert str(root) not in json.dumps(data.metadata)  # the same copy gives the same dataset on any machine
    assert StateDataset.load(data.save(tmp_path / "head.npz")).equals(data)


def test_a_params_root_makes_head_frames_the_atari_ood_states(head_root):
    """The pipeline's collection (the main runs and the independent ensembles): OOD from the copy when given."""
    root, _ = head_root
    model = make_agent("ppo", "baseline", SEAQUEST, seed=0, n_envs=2, overrides=dict(TINY))
    cfg = dataclasses.replace(load_run_config(), protocol="appendix", n_id_states=8, n_ood_states=6,
                              max_episode_steps=20, skip_first=2, atari_head_root=root)
    data = collect_states(cfg, model, SEAQUEST, seed=0)
    ood, head = data.subset(data.labels == 1), atari_head_ood_dataset(root, SEAQUEST, 6, seed=2)
    assert (data.labels == 0).sum() == 8 and set(ood.source) == {HEAD_SOURCE}
    np.testing.assert_array_equal(ood.states, head.states)
    assert [ood.config_json(i) for i in range(6)] == [head.config_json(i) for i in range(6)]
    assert collection_protocol(data) == HEAD_SOURCE and collection_actions(data) == "sampled actions, vote inference"
    coverage = source_coverage(data)
    assert coverage.loc[0, "ood_source"] == HEAD_SOURCE and coverage.loc[0, "check"] == HUMAN_PLAY
    edited = collect_states(dataclasses.replace(cfg, atari_head_root=None), model, SEAQUEST, seed=0)
    assert set(edited.source[edited.labels == 1]) == {"level"}  # the default: edited game states
    np.testing.assert_array_equal(edited.states[:8], data.states[:8])  # the same ID states either way
    with pytest.raises(FileNotFoundError, match="Atari-HEAD root"):
        collect_states(dataclasses.replace(cfg, atari_head_root=root / "missing"), model, SEAQUEST, seed=0)
