"""Pixel perturbations (appendix H) and the noise OOD of the meta-optimization (section 5)."""

from __future__ import annotations

import numpy as np
import pytest

from paper_lib.ood.pixels import DEFAULT_MASK, NOISE_AMPLITUDES, PIXEL_PERTURBATIONS, noise_ood, perturb_pixels


@pytest.fixture()
def states() -> np.ndarray:
    """Stacked-frame-like uint8 states that include the extremes 0 and 255 (clipping must show)."""
    rng = np.random.default_rng(0)
    s = rng.integers(0, 256, size=(6, 84, 84, 4), dtype=np.uint8)
    s[:, :10] = 0
    s[:, -10:] = 255
    return s


@pytest.mark.parametrize("kind", PIXEL_PERTURBATIONS)
def test_shape_dtype_kept_input_untouched_and_seeded(states, kind):
    before = states.copy()
    out = perturb_pixels(states, kind, np.random.default_rng(1))
    assert out.shape == states.shape and out.dtype == np.uint8
    np.testing.assert_array_equal(states, before)
    np.testing.assert_array_equal(out, perturb_pixels(states, kind, np.random.default_rng(1)))


def test_black_and_white(states):
    assert (perturb_pixels(states, "black", np.random.default_rng(0)) == 0).all()
    assert (perturb_pixels(states, "white", np.random.default_rng(0)) == 255).all()


@pytest.mark.parametrize("kind", sorted(NOISE_AMPLITUDES))
def test_noise_bounded_clipped_and_nonzero(states, kind):
    amplitude = NOISE_AMPLITUDES[kind]
    out = perturb_pixels(states, kind, np.random.default_rng(2))
    delta = out.astype(int) - states.astype(int)
    assert np.abs(delta).max() <= amplitude
    inner = (states > 0) & (states < 255)  # only zero noise leaves these unchanged
    assert (delta[inner] != 0).mean() > 0.95
    assert delta[states <= 255 - amplitude].max() == amplitude  # the full range is drawn
    assert delta[states >= amplitude].min() == -amplitude
    assert (delta[states == 0] >= 0).all() and (delta[states == 255] <= 0).all()  # clipped, no wrap-around
    assert perturb_pixels(states, kind, np.random.default_rng(3)).tolist() != out.tolist()


def test_mask_is_a_constant_rectangle_and_the_rest_unchanged(states):
    top, left, height, width = DEFAULT_MASK
    out = perturb_pixels(states, "mask", np.random.default_rng(0))
    assert (out[:, top:top + height, left:left + width, :] == 0).all()
    inside = np.zeros(states.shape[1:3], dtype=bool)
    inside[top:top + height, left:left + width] = True
    np.testing.assert_array_equal(out[:, ~inside], states[:, ~inside])
    custom = perturb_pixels(states, "mask", np.random.default_rng(0), mask=(0, 50, 84, 34), mask_value=128)
    assert (custom[:, :, 50:] == 128).all()
    np.testing.assert_array_equal(custom[:, :, :50], states[:, :, :50])


def test_bad_inputs_raise(states):
    with pytest.raises(ValueError, match="Unknown pixel perturbation 'blur': use one of \\['black', 'white'"):
        perturb_pixels(states, "blur", np.random.default_rng(0))
    with pytest.raises(ValueError, match="states must be uint8 images"):
        perturb_pixels(states / 255.0, "black", np.random.default_rng(0))
    with pytest.raises(ValueError, match="does not fit in 84x84"):
        perturb_pixels(states, "mask", np.random.default_rng(0), mask=(60, 0, 30, 10))
    with pytest.raises(ValueError, match="mask_value=300"):
        perturb_pixels(states, "mask", np.random.default_rng(0), mask_value=300)
    with pytest.raises(ValueError, match="numpy Generator"):
        perturb_pixels(states, "noise50", 0)  # type: ignore[arg-type]


def test_noise_ood_on_float_vectors():
    rng = np.random.default_rng(0)
    id_states = rng.normal(size=(500, 17)) * np.linspace(0.1, 5.0, 17)
    id_states[:, 3] = 1.5  # an element that never varies gets no noise
    out = noise_ood(id_states, np.random.default_rng(4))
    assert out.shape == id_states.shape and out.dtype == id_states.dtype
    bound = 2.0 * id_states.std(axis=0)
    delta = out - id_states
    assert (np.abs(delta) <= bound + 1e-12).all()
    np.testing.assert_array_equal(delta[:, 3], 0.0)
    # uniform on [-bound, bound]: std bound / sqrt(3)
    np.testing.assert_allclose(delta.std(axis=0)[bound > 0], bound[bound > 0] / np.sqrt(3), rtol=0.15)
    np.testing.assert_array_equal(out, noise_ood(id_states, np.random.default_rng(4)))
    assert np.abs(noise_ood(id_states, np.random.default_rng(4), magnitude=0.5) - id_states).max() <= bound.max() / 4
    f32 = noise_ood(id_states.astype(np.float32), np.random.default_rng(4))
    assert f32.dtype == np.float32


def test_noise_ood_on_uint8_images(states):
    out = noise_ood(states, np.random.default_rng(5))
    assert out.shape == states.shape and out.dtype == np.uint8
    bound = 2.0 * states.astype(float).std(axis=0)
    delta = out.astype(float) - states
    assert (np.abs(delta) <= np.ceil(bound)).all() and (delta != 0).mean() > 0.5
    np.testing.assert_array_equal(delta[:, :10], 0)  # always-black rows: std 0, no noise
    np.testing.assert_array_equal(out, noise_ood(states, np.random.default_rng(5)))


def test_noise_ood_bad_inputs():
    with pytest.raises(ValueError, match="at least 2 states"):
        noise_ood(np.zeros((1, 4)), np.random.default_rng(0))
    with pytest.raises(ValueError, match="float .* or uint8"):
        noise_ood(np.zeros((3, 4), dtype=np.int64), np.random.default_rng(0))
    with pytest.raises(ValueError, match="magnitude=-1"):
        noise_ood(np.zeros((3, 4)), np.random.default_rng(0), magnitude=-1)
    with pytest.raises(ValueError, match="NaN or inf"):
        noise_ood(np.array([[0.0, np.nan], [1.0, 2.0]]), np.random.default_rng(0))
