"""Frame stacks stored as one frame sequence: bit-identical round trips, whatever the states look like."""

from __future__ import annotations

import numpy as np
import pytest

from paper_lib.ood import frame_store
from paper_lib.ood.datasets import FORMAT, FORMAT_FRAMES, StateDataset


def played(rng: np.random.Generator, episode_lengths: list[int], k: int = 4, size: int = 6) -> np.ndarray:
    """Stacks as VecFrameStack gives them: each episode slides a window over its own frames."""
    stacks = []
    for n in episode_lengths:
        frames = rng.integers(0, 256, size=(n + k - 1, size, size), dtype=np.uint8)
        stacks += [frames[t:t + k].transpose(1, 2, 0) for t in range(n)]
    return np.stack(stacks)


def dataset(states: np.ndarray) -> StateDataset:
    n = len(states)
    return StateDataset(states=states, labels=np.zeros(n), source=["id"] * n, config_index=np.full(n, -1),
                        episode=np.zeros(n), step=np.arange(n))


def test_played_episodes_store_each_frame_once_and_rebuild_exactly():
    stacks = played(np.random.default_rng(0), [5, 1, 7])
    frames, new_stack = frame_store.to_frames(stacks)
    assert new_stack.tolist() == [True] + [False] * 4 + [True] + [True] + [False] * 6
    assert frames.shape == (3 * 4 + 10, 6, 6)  # three full stacks, then one frame per continuing state
    rebuilt = frame_store.from_frames(frame_store.unpack(frame_store.pack(frames), (6, 6)), new_stack, 4)
    assert rebuilt.dtype == np.uint8 and np.array_equal(rebuilt, stacks)


@pytest.mark.parametrize("make", [
    lambda rng: rng.integers(0, 256, size=(9, 5, 5, 4), dtype=np.uint8),  # nothing continues
    lambda rng: np.zeros((6, 5, 5, 4), dtype=np.uint8),  # black frames: everything "continues"
    lambda rng: played(rng, [8])[rng.permutation(8)],  # shuffled states of one episode
    lambda rng: played(rng, [4, 4], k=2),  # another stack depth
    lambda rng: np.zeros((0, 5, 5, 4), dtype=np.uint8),  # empty
])
def test_any_stacks_round_trip_bit_identically(make):
    stacks = make(np.random.default_rng(1))
    frames, new_stack = frame_store.to_frames(stacks)
    assert np.array_equal(frame_store.from_frames(frames, new_stack, stacks.shape[-1]), stacks)


def test_dataset_files_use_the_frame_store_for_stacks_only(tmp_path):
    stacks = dataset(played(np.random.default_rng(2), [30, 20]))
    loaded = StateDataset.load(stacks.save(tmp_path / "atari.npz"))
    assert loaded.equals(stacks) and loaded.states.flags.writeable
    with np.load(tmp_path / "atari.npz") as f:
        assert str(f["format"]) == FORMAT_FRAMES and "states" not in f.files
    vectors = dataset(np.random.default_rng(3).normal(size=(10, 17)))
    assert StateDataset.load(vectors.save(tmp_path / "mujoco.npz")).equals(vectors)
    with np.load(tmp_path / "mujoco.npz") as f:
        assert str(f["format"]) == FORMAT and "states" in f.files


def test_format_1_files_of_stacks_still_load(tmp_path):
    """Datasets written before the frame store held the stacks as they are."""
    data = dataset(played(np.random.default_rng(4), [6]))
    arrays = dict(format=np.array(FORMAT), states=data.states, labels=data.labels, source=data.source,
                  config_index=data.config_index, episode=data.episode, step=data.step,
                  configs=np.array("[]"), metadata=np.array("{}"))
    np.savez_compressed(tmp_path / "old.npz", **arrays)
    assert StateDataset.load(tmp_path / "old.npz").equals(data)


def test_damaged_frame_stores_raise_clear_errors(tmp_path):
    stacks = played(np.random.default_rng(5), [5])
    frames, new_stack = frame_store.to_frames(stacks)
    with pytest.raises(ValueError, match="need 8"):
        frame_store.from_frames(frames[:-1], new_stack, 4)
    with pytest.raises(ValueError, match="first state must start a stack"):
        frame_store.from_frames(frames, ~new_stack, 4)
    with pytest.raises(ValueError, match="uint8 frame stacks"):
        frame_store.to_frames(stacks.astype(np.float32))
    path = dataset(stacks).save(tmp_path / "d.npz")
    with np.load(path) as f:
        arrays = {k: f[k] for k in f.files}
    arrays["frames_xz"] = arrays["frames_xz"][:-8]  # a truncated lzma stream
    np.savez_compressed(path, **arrays)
    with pytest.raises(ValueError, match="not a readable StateDataset.*run the collection that writes it again"):
        StateDataset.load(path)
