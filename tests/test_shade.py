"""refine.shade: a faint shade beside a removed mover, relit to the sources' light.

Small scenes built here, the sources aligned with the reference (identity fields),
so that what the rule sees is exactly what was planted."""

from __future__ import annotations

import cv2
import numpy as np

from dynremove.refine.shade import apply_offset, relight_shade

H, W = 200, 260


def _ground(seed: int = 0) -> np.ndarray:
    """A textured, mid-grey ground (BGR uint8)."""
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.normal(0, 12, (H, W)).astype(np.float32), (0, 0), 1.5)
    base = np.stack([110 + tex, 125 + tex, 140 + tex], -1)
    return np.clip(base, 0, 255).astype(np.uint8)


def _scene(shade_in_reference: float, light_in_sources: float):
    """A replaced disc (the mover's place) with a soft blob beside it, 40 × 60 px:
    the reference's ground × ``shade_in_reference`` there, the sources' ×
    ``light_in_sources``. Returns (clean, sources, fields, replaced, blob)."""
    ground = _ground()
    yy, xx = np.mgrid[0:H, 0:W]
    replaced = (yy - 100) ** 2 + (xx - 100) ** 2 < 35 ** 2
    blob = ((yy - 100) / 30.0) ** 2 + ((xx - 160) / 40.0) ** 2 < 1
    soft = cv2.GaussianBlur(blob.astype(np.float32), (0, 0), 3.0)[..., None]
    clean = np.clip(ground * (1 - soft * (1 - shade_in_reference)), 0, 255).astype(np.uint8)
    src = np.clip(ground * (1 - soft * (1 - light_in_sources)), 0, 255).astype(np.uint8)
    sources = np.stack([src] * 4)
    fields = [np.ascontiguousarray(np.stack([xx, yy], -1).astype(np.float32))] * 4
    return clean, sources, fields, replaced, blob


def _L(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img.astype(np.float32) / 255, cv2.COLOR_BGR2Lab)[..., 0]


def _relit(clean, sources, fields, replaced):
    r = relight_shade(clean, sources, fields, replaced, reach_px=120, min_dl=3.0,
                      max_de=15.0)
    return r, (clean if r is None else apply_offset(clean, r.offset, r.relit))


def test_a_soft_shadow_beside_the_mover_is_relit_to_the_ground_around_it():
    clean, sources, fields, replaced, blob = _scene(0.88, 1.0)  # 12 % darker: ~5 L*
    core = cv2.erode(blob.view(np.uint8), np.ones((15, 15), np.uint8)) > 0
    ground = _L(sources[0])
    before = (ground - _L(clean))[core].mean()
    r, out = _relit(clean, sources, fields, replaced)
    assert before > 4.0 and r is not None and r.relit[core].all()
    after = (ground - _L(out))[core].mean()
    assert abs(after) < 1.5, (before, after)  # measured 6.3 -> 1.0 L* (a JND is 1-2)
    # the texture is the reference's own: its detail is unchanged
    hp = lambda im: _L(im) - cv2.GaussianBlur(_L(im), (0, 0), 4.0)  # noqa: E731
    assert np.abs(hp(out) - hp(clean))[core].mean() < 0.5
    assert not (r.relit & ~cv2.dilate(blob.view(np.uint8), np.ones((21, 21))).astype(bool)
                & ~replaced).any()  # only the shade (and its feathered rim)


def test_a_patch_the_sources_show_lighter_is_not_a_shadow():
    """The reference plain, the sources lighter over a patch (glare, their own light):
    the reference is no darker there than around it, so nothing is relit (relit, it
    came out a whiter patch on white paper in a review of real bursts)."""
    clean, sources, fields, replaced, blob = _scene(1.0, 1.12)
    r, out = _relit(clean, sources, fields, replaced)
    assert r is None or not (r.relit & blob).any()


def test_a_hard_shadow_is_left():
    """40 % darker (ΔE far over select_shade_max_de): its blurred rim would come out as a
    light outline, so it is left to the fill (or kept)."""
    clean, sources, fields, replaced, blob = _scene(0.6, 1.0)
    r, _ = _relit(clean, sources, fields, replaced)
    assert r is None or not (r.relit & blob).any()
