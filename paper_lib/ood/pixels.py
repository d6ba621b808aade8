"""Pixel perturbations of ID states (paper appendix H) and the noise OOD of the meta-optimization (section 5).

Appendix H replaces or corrupts Seaquest frames: a black frame, a white frame, uniform
noise of +-50, +-100 or +-150 grey levels (its text says Gaussian, its figures "Uniform
Noise [-50;50]": we follow the figures), and a static mask over part of the frame.
The paper moved away from these (they say little about real OOD states) but reports
them; they are kept as a sanity check of the uncertainty measures.

Section 5 makes OOD states for the 190-trial Optuna search by adding uniform noise of
2x the element-wise standard deviation of the ID observations: cheap, for any obs space.
"""

from __future__ import annotations

import numpy as np

PIXEL_PERTURBATIONS: tuple[str, ...] = ("black", "white", "noise50", "noise100", "noise150", "mask")
NOISE_AMPLITUDES: dict[str, int] = {"noise50": 50, "noise100": 100, "noise150": 150}
# (top, left, height, width) on the 84x84 agent frame: the central 42x42 square, where
# the action of all four games takes place. Static: the same pixels in every frame.
DEFAULT_MASK: tuple[int, int, int, int] = (21, 21, 42, 42)


def _check_rng(rng: np.random.Generator) -> None:
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}.")


def perturb_pixels(states: np.ndarray, kind: str, rng: np.random.Generator, *,
                   mask: tuple[int, int, int, int] = DEFAULT_MASK, mask_value: int = 0) -> np.ndarray:
    """A perturbed copy of uint8 image states (N, H, W, C), channel-last as SB3 stacks them.

    ``mask`` is (top, left, height, width) in pixels; the masked pixels of every frame
    and stacked channel are set to ``mask_value``.
    """
    if kind not in PIXEL_PERTURBATIONS:
        raise ValueError(f"Unknown pixel perturbation {kind!r}: use one of {list(PIXEL_PERTURBATIONS)}.")
    _check_rng(rng)
    states = np.asarray(states)
    if states.dtype != np.uint8 or states.ndim != 4:
        raise ValueError(f"states must be uint8 images (N, H, W, C), got {states.dtype} {states.shape}: "
                         f"pass the raw stacked frames, not normalized ones.")
    if kind == "black":
        return np.zeros_like(states)
    if kind == "white":
        return np.full_like(states, 255)
    if kind in NOISE_AMPLITUDES:
        amplitude = NOISE_AMPLITUDES[kind]
        noise = rng.integers(-amplitude, amplitude + 1, size=states.shape, dtype=np.int16)
        return np.clip(states.astype(np.int16) + noise, 0, 255).astype(np.uint8)
    top, left, height, width = mask
    h, w = states.shape[1:3]
    if not (0 <= top and 0 <= left and height > 0 and width > 0 and top + height <= h and left + width <= w):
        raise ValueError(f"mask={mask} (top, left, height, width) does not fit in {h}x{w} frames.")
    if not 0 <= mask_value <= 255:
        raise ValueError(f"mask_value={mask_value}: need a grey level in [0, 255].")
    out = states.copy()
    out[:, top:top + height, left:left + width, :] = mask_value
    return out


def noise_ood(id_states: np.ndarray, rng: np.random.Generator, magnitude: float = 2.0) -> np.ndarray:
    """ID states plus uniform noise in +-``magnitude`` x the element-wise std of the ID states.

    Works on float vectors (MuJoCo) and on uint8 images (rounded, clipped to [0, 255],
    dtype kept). Elements that never vary in the ID data get no noise.
    """
    _check_rng(rng)
    id_states = np.asarray(id_states)
    if id_states.ndim < 2 or len(id_states) < 2:
        raise ValueError(f"id_states must hold at least 2 states along axis 0 to have a std, got {id_states.shape}.")
    if not (np.issubdtype(id_states.dtype, np.floating) or id_states.dtype == np.uint8):
        raise ValueError(f"id_states must be float (vectors) or uint8 (images), got {id_states.dtype}.")
    if not (np.isfinite(magnitude) and magnitude > 0):
        raise ValueError(f"magnitude={magnitude}: need a positive number (the paper uses 2.0).")
    values = id_states.astype(np.float64)
    if not np.isfinite(values).all():
        raise ValueError("id_states contain NaN or inf.")
    scale = magnitude * values.std(axis=0)
    noisy = values + rng.uniform(-1.0, 1.0, size=values.shape) * scale
    if id_states.dtype == np.uint8:
        return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return noisy.astype(id_states.dtype)
