"""The compiled CIE76 ΔE equals NumPy's norm bit for bit, for every broadcast the fill uses."""

import numpy as np
import pytest

from dynremove.refine.colour import delta_e, pairwise_delta_e


def _lab(rng, shape, dtype=np.float32):
    return (rng.random(shape + (3,)) * [100, 128, 128] - [0, 64, 64]).astype(dtype)


@pytest.mark.parametrize("sa, sb", [
    ((40, 50), (40, 50)),          # two images
    ((5, 40, 50), (40, 50)),       # every source against the reference
    ((40, 50), (5, 40, 50)),       # the same, operands swapped
    ((5, 300), (300,)),            # sampled pixels against one row of colours
    ((6, 1, 70), (1, 6, 70)),      # all pairs by broadcasting
    ((40, 50), ()),                # one colour
    ((0, 50), (50,)),              # empty
])
def test_delta_e_equals_numpy_norm(sa, sb):
    rng = np.random.default_rng(0)
    a, b = _lab(rng, sa), _lab(rng, sb)
    want = np.linalg.norm(a - b, axis=-1)
    got = delta_e(a, b)
    assert got.dtype == want.dtype and got.shape == want.shape
    np.testing.assert_array_equal(got, want)


def test_delta_e_float64_and_mixed():
    rng = np.random.default_rng(1)
    a, b = _lab(rng, (30, 20), np.float64), _lab(rng, (30, 20))
    np.testing.assert_array_equal(delta_e(a, b), np.linalg.norm(a - b, axis=-1))
    assert delta_e(a, b).dtype == np.float64


@pytest.mark.parametrize("shape", [(6, 500), (4, 20, 30), (1, 7)])
def test_pairwise_delta_e_equals_numpy(shape):
    rng = np.random.default_rng(2)
    v = _lab(rng, shape)
    want = np.linalg.norm(v[:, None] - v[None], axis=-1)
    got = pairwise_delta_e(v)
    assert got.shape == want.shape and got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)


def test_delta_e_refuses_non_colour_arrays():
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        delta_e(np.zeros((4, 2)), np.zeros((4, 2)))
