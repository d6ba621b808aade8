"""Frame stacks stored as the frame sequence they were cut from: exact, and 10-30x smaller.

An Atari state is ``k`` stacked frames (84x84x4 uint8, channels last, as VecFrameStack gives
them), and the next state of the same episode repeats ``k - 1`` of them. So a dataset of
frame stacks is stored as each frame once, in play order, and rebuilt by slicing: a state
that continues the previous one adds one frame, any other state (an episode's first kept
state, a derived or shuffled one) adds all ``k``. Which is which is decided by comparing the
frames themselves, not from episode numbers, so the rebuilt stacks are bit-identical to the
saved ones for any input; in the worst case nothing continues and every frame is stored as
before. The frame sequence is then compressed with lzma (standard library, xz format with
its CRC check), which finds the static backgrounds of consecutive frames that a 32 kB
deflate window misses.
"""

from __future__ import annotations

import lzma

import numpy as np

#: xz's default preset: 9 saves ~10% more at ~7x the compressor memory (674 MB).
LZMA_PRESET = 6


def is_frame_stacks(states: np.ndarray) -> bool:
    """Whether ``states`` look like stacked uint8 frames (N, H, W, k >= 2), the layout this module stores."""
    return states.dtype == np.uint8 and states.ndim == 4 and states.shape[-1] >= 2


def continues_previous(stacks: np.ndarray) -> np.ndarray:
    """(N,) bool: state i's older frames are state i-1's newer ones (always False for state 0)."""
    out = np.zeros(len(stacks), dtype=bool)
    for i in range(1, len(stacks)):  # one state at a time: no (N, H, W, k) temporary
        out[i] = np.array_equal(stacks[i, ..., :-1], stacks[i - 1, ..., 1:])
    return out


def to_frames(stacks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(frames (M, H, W), new_stack (N,) bool): the frame sequence and which states start a new stack."""
    if not is_frame_stacks(stacks):
        raise ValueError(f"expected uint8 frame stacks of shape (N, H, W, k >= 2), got {stacks.dtype} "
                         f"{stacks.shape}; store other states as they are.")
    new_stack = ~continues_previous(stacks)
    parts = [stacks[i].transpose(2, 0, 1) if new_stack[i] else stacks[i, None, ..., -1] for i in range(len(stacks))]
    frames = np.concatenate(parts) if parts else np.empty((0, *stacks.shape[1:3]), dtype=np.uint8)
    return np.ascontiguousarray(frames), new_stack


def from_frames(frames: np.ndarray, new_stack: np.ndarray, n_stack: int) -> np.ndarray:
    """The (N, H, W, n_stack) stacks that ``to_frames`` was given, from its output."""
    new_stack = np.asarray(new_stack, dtype=bool)
    if len(new_stack) and not new_stack[0]:
        raise ValueError("new_stack[0] is False: the first state must start a stack (damaged frame store).")
    last = np.cumsum(np.where(new_stack, n_stack, 1)) - 1  # index of each state's newest frame
    expected = int(last[-1]) + 1 if len(last) else 0
    if len(frames) != expected:
        raise ValueError(f"the frame store has {len(frames)} frames but its {len(new_stack)} states need "
                         f"{expected} (damaged frame store).")
    stacks = np.empty((len(new_stack), *frames.shape[1:], n_stack), dtype=frames.dtype)
    for j in range(n_stack):
        stacks[..., j] = frames[last - (n_stack - 1 - j)]
    return stacks


def pack(frames: np.ndarray) -> np.ndarray:
    """The frames' bytes, lzma-compressed, as a uint8 array (what an .npz can hold)."""
    return np.frombuffer(lzma.compress(np.ascontiguousarray(frames).tobytes(), preset=LZMA_PRESET), dtype=np.uint8)


def unpack(blob: np.ndarray, frame_shape: tuple[int, int]) -> np.ndarray:
    """The (M, H, W) uint8 frames that ``pack`` compressed."""
    data = lzma.decompress(np.asarray(blob, dtype=np.uint8).tobytes())
    size = int(np.prod(frame_shape))
    if len(data) % size:
        raise ValueError(f"{len(data)} bytes of frames do not divide into frames of {frame_shape} "
                         "(damaged frame store).")
    return np.frombuffer(data, dtype=np.uint8).reshape(-1, *frame_shape)
