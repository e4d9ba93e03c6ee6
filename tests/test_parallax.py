"""The plane + parallax sweep recovers hidden 3-D structure (refine.parallax).

A synthetic scene with exact plane + parallax geometry: a textured curved wall
with blocks standing out of it (a larger γ) — the visible parallax must not be
that of a plane, or each source's scale k_s cannot be told from the affine
term — seen by a reference and four sources,
x_s ~ H_s x̃_r + μ_s ẽ_s with μ_s = k_s γ + an affine term (each H_s induced
by a different plane). The block is hidden in the reference by a mover.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynremove.method.geometry import TwoView
from dynremove.refine import parallax as px
from dynremove.refine.fields import background_field, blurred_lab, sample_bilinear

H, W = 120, 160
BLOCK = (slice(40, 80), slice(60, 110))  # rows, cols of the block standing out


def _cross(e):
    return np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]], float)


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    # a texture on reference coordinates: smooth colour noise, strong enough to match
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (H, W, 3)).astype(np.float32), (0, 0), 2.0)
    tex = cv2.normalize(tex, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    # a curved wall (a plane would make k_s unidentifiable: its γ is affine)
    gamma = 2.0 * gx / W + 2.0 * np.sin(2 * np.pi * gx / W) * np.cos(np.pi * gy / H)
    gamma[BLOCK] = 6.0
    gamma[95:115, 10:40] = 8.0  # a second block, visible
    gamma[5:25, 120:150] = 5.0  # a third
    views, fields, sources = [], [], []
    for k in range(4):
        t = np.array([8.0 * (k - 1.5), 3.0 * (k % 2), 0.0])
        Hm = np.array([[1.0, 0.002 * k, t[0]], [-0.001 * k, 1.0, t[1]], [0.0, 0.0, 1.0]])
        e = np.array([1.0, 0.15 * (k - 1.5), 0.0])
        e /= np.linalg.norm(e)
        kk = [1.0, -0.7, 1.4, 0.5][k]
        aff = 0.3 * k * (gx / W) - 0.2 * (gy / H)
        mu = kk * gamma + aff
        fx, fy = px.project(Hm, e, mu, gx, gy)
        field = np.stack([fx, fy], -1).astype(np.float32)
        # render the source: invert the map by fixed-point iteration
        inv = np.stack([gx, gy], -1).astype(np.float32)
        for _ in range(30):
            fwd = cv2.remap(field, inv[..., 0], inv[..., 1], cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE)
            inv += np.stack([gx, gy], -1).astype(np.float32) - fwd
        src = cv2.remap(tex, inv[..., 0], inv[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REFLECT)
        F = _cross(e) @ Hm
        views.append(TwoView(F=F / np.linalg.norm(F), H=Hm, n_matches=100, n_inliers_F=100,
                             n_inliers_H=100, parallax_px=12.0))
        fields.append(field)
        sources.append(src)
    return tex, gamma, views, fields, sources


def test_epipole_is_the_null_vector():
    _, _, views, _, _ = _scene()
    for v in views:
        e = px.epipole(v.F)
        assert np.linalg.norm(v.F.T @ e) < 1e-9 and abs(np.linalg.norm(e) - 1) < 1e-12


def test_fit_recovers_a_common_gamma():
    _, gamma, views, fields, _ = _scene()
    visible = np.ones((H, W), bool)
    m = px.fit_parallax(fields, views, visible)
    assert m is not None
    assert np.all(m.mad_px < 0.05), m.mad_px
    # every source's μ is k_s γ + affine: the ratio of the k's is the true ratio
    # (up to sign: an epipole's sign is arbitrary)
    true_k = np.array([1.0, -0.7, 1.4, 0.5])
    np.testing.assert_allclose(np.abs(m.coef[:, 0] / m.coef[m.anchor, 0]),
                               np.abs(true_k / true_k[m.anchor]), rtol=0.02)


def test_sgm_beats_winner_take_all_on_noise():
    rng = np.random.default_rng(1)
    truth = np.zeros((40, 60), int)
    truth[:, 30:] = 12
    D = 24
    cost = rng.uniform(0, 1.0, (40, 60, D)).astype(np.float32)
    cost[np.arange(40)[:, None], np.arange(60)[None], truth] -= 0.5
    wta = np.argmin(cost, -1)
    reg = np.argmin(px.sgm(cost, np.float32(0.5), np.float32(2.0)), -1)
    assert (reg == truth).mean() > 0.95 > (wta == truth).mean()


def test_sweep_recovers_the_hidden_block():
    tex, gamma, views, fields, sources = _scene()
    hole = np.zeros((H, W), bool)
    hole[30:90, 50:120] = True  # the mover hides the whole block and some wall
    model = px.fit_parallax(fields, views, ~hole)
    membrane = [background_field(f, hole) for f in fields]
    labs = [blurred_lab(s, 0.0) for s in sources]
    swept, g = px.sweep_fields(labs, views, model, hole, membrane, step_px=0.5)
    inner = np.zeros_like(hole)
    inner[BLOCK] = True
    inner[:, :] &= hole
    err_m = np.mean([np.hypot(*(m - f).transpose(2, 0, 1))[inner].mean()
                     for m, f in zip(membrane, fields)])
    err_s = np.mean([np.hypot(*(s - f).transpose(2, 0, 1))[inner].mean()
                     for s, f in zip(swept, fields)])
    assert err_m > 3.0, "the membrane cannot know the hidden block's depth"
    assert err_s < 1.0 and err_s < err_m / 4, (err_s, err_m)
    # the fill through the swept fields shows the wall and the block as they are
    lab_t = blurred_lab(tex, 0.0)
    dE = [np.linalg.norm(blurred_lab(sample_bilinear(s, f)[0], 0.0) - lab_t, axis=-1)[inner]
          for s, f in zip(sources, swept)]
    assert np.median(np.concatenate(dE)) < 5.0
    # outside the hole nothing changes
    for s, m in zip(swept, membrane):
        np.testing.assert_array_equal(s[~hole], m[~hole])


@pytest.mark.parametrize("n_with_F", [0, 1])
def test_too_few_sources_with_geometry_keep_the_membrane(n_with_F):
    _, _, views, fields, sources = _scene()
    views = [v if i < n_with_F else TwoView(F=None, H=v.H, n_matches=0, n_inliers_F=0,
                                             n_inliers_H=0) for i, v in enumerate(views)]
    assert px.fit_parallax(fields, views, np.ones((H, W), bool)) is None


def test_select_fill_with_the_sweep_shows_the_hidden_block():
    """End to end through ``select_fill`` (``select_sweep`` on): a mover hides the
    block in the reference; the fill through the swept fields restores it, the
    membrane fill does not."""
    from dynremove.params import preset
    from dynremove.refine.select import select_fill

    tex, _, views, _, sources = _scene()
    ref = tex.copy()
    mask = np.zeros((H, W), bool)
    mask[34:86, 56:114] = True
    ref[mask] = (30, 200, 60)  # the mover, a colour far from the texture
    lab_t = blurred_lab(tex, 0.0)
    err = {}
    for sweep in (False, True):
        # (the sweep alone: no growth, no re-alignment, no seam blend; the seams
        # between this scene's sources are their fields' misalignment, which the
        # blend smooths: median 4.7 -> 5.5 here)
        p = preset("default").replace(select_sweep=sweep, select_grow_px=0, fuse_realign=0,
                                      select_seam_levels=0)
        sel = select_fill(ref, np.stack(sources), views, mask, p)
        assert sel.consensus_mode == "parallax"
        dE = np.linalg.norm(blurred_lab(sel.clean, 0.0) - lab_t, axis=-1)
        err[sweep] = float(np.median(dE[BLOCK]))
    assert err[True] < 5.0 and err[True] < err[False] / 2, err


def test_a_planar_scene_is_not_identifiable():
    """A plane's γ is affine in (x, y): k_s cannot be fitted, the sweep is refused."""
    _, _, views, fields, _ = _scene()
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    flat = []
    for k, v in enumerate(views):
        mu = [1.0, -0.7, 1.4, 0.5][k] * (2.0 * gx / W) + 0.3 * k * gx / W
        fx, fy = px.project(v.H, px.epipole(v.F), mu, gx, gy)
        flat.append(np.stack([fx, fy], -1).astype(np.float32))
    assert px.fit_parallax(flat, views, np.ones((H, W), bool)) is None
    assert px.fit_parallax(fields, views, np.ones((H, W), bool)) is not None


def test_epipolar_search_finds_static_structure_and_not_a_mover():
    """A reference pixel of static 3-D structure (part of a block, off every
    plane, at a depth the visible pixels span) has a match on its epipolar line
    in each source; a pixel of a mover pasted into the reference only has none."""
    tex, gamma, views, fields, sources = _scene()
    ref = tex.copy()
    rng = np.random.default_rng(7)
    mover = (slice(60, 100), slice(115, 150))
    blob = cv2.GaussianBlur(rng.uniform(0, 255, (40, 35, 3)).astype(np.float32), (0, 0), 2.0)
    ref[mover] = cv2.normalize(blob, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    region = np.zeros((H, W), bool)
    region[45:75, 65:85] = True  # inside the block of γ = 6 (its rest stays visible)
    region[mover] = True
    lab_r = blurred_lab(ref, 1.0)
    block = np.zeros((H, W), bool)
    block[47:73, 67:83] = True  # away from the block's depth edges
    core = np.zeros((H, W), bool)
    core[65:95, 120:145] = True
    for k in range(4):
        cost, mu = px.epipolar_search(lab_r, blurred_lab(sources[k], 1.0), views[k], fields[k],
                                      ~region, region)
        assert np.all(np.isinf(cost[~region]))
        assert np.median(cost[block]) < 4.0, (k, np.median(cost[block]))
        assert np.median(cost[core]) > 12.0, (k, np.median(cost[core]))
        # and at the right depth: μ within a pixel or two of the true match's
        true_mu = px._mu_of(views[k].H, px.epipole(views[k].F), *np.nonzero(block)[::-1],
                            fields[k][block][:, 0], fields[k][block][:, 1])
        e = px.epipole(views[k].F)
        gy_, gx_ = np.nonzero(block)
        p1 = px.project(views[k].H, e, mu[block].astype(np.float64), gx_, gy_)
        p0 = px.project(views[k].H, e, true_mu, gx_, gy_)
        assert np.median(np.hypot(p1[0] - p0[0], p1[1] - p0[1])) < 2.0
        # where inspect says the match lies: the source's pixel of the true match
        at = px.line_points(views[k], mu)
        assert np.isnan(at[~region]).all() and np.isfinite(at[region]).all()
        assert np.median(np.hypot(*(at[block] - fields[k][block]).T)) < 2.0


def test_the_anchor_is_the_source_of_widest_parallax_not_the_noisiest():
    """γ is measured in the source whose matches depart most from its homography.
    On a mostly planar scene (blocks standing out of a flat wall) every source's
    median departure sits on the wall: there, matches with more noise would win,
    and γ would be that noise (the other k_s fitted near 0)."""
    rng = np.random.default_rng(3)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    gamma = np.zeros((H, W))
    gamma[10:60, 10:70] = 6.0  # blocks on a flat wall: about 30 % of the image
    gamma[70:110, 90:150] = 4.0
    views, fields = [], []
    true_k = [1.0, -0.7, 1.4, 0.2]
    for k in range(4):
        Hm = np.array([[1.0, 0.002 * k, 8.0 * (k - 1.5)], [-0.001 * k, 1.0, 3.0 * (k % 2)],
                       [0.0, 0.0, 1.0]])
        e = np.array([1.0, 0.15 * (k - 1.5), 0.0])
        e /= np.linalg.norm(e)
        fx, fy = px.project(Hm, e, true_k[k] * gamma, gx, gy)
        field = np.stack([fx, fy], -1).astype(np.float32)
        if k == 3:  # the smallest parallax, the noisiest matches (on its lines)
            field += (rng.normal(0, 0.6, (H, W))[..., None] * e[:2]).astype(np.float32)
        F = _cross(e) @ Hm
        views.append(TwoView(F=F / np.linalg.norm(F), H=Hm, n_matches=100, n_inliers_F=100,
                             n_inliers_H=100, parallax_px=12.0))
        fields.append(field)
    m = px.fit_parallax(fields, views, np.ones((H, W), bool))
    assert m is not None and m.anchor == 2, m
    np.testing.assert_allclose(np.abs(m.coef[:3, 0] / m.coef[2, 0]),
                               np.abs(np.array(true_k[:3]) / true_k[2]), rtol=0.05)


def _striped_wall(h, w, rng):
    """Vertical stripes 9 px apart with ``rng``'s noise, blurred: (h, w, 3) BGR
    uint8, and the pixel grid gx, gy (h, w) float32."""
    xx = np.arange(w, dtype=np.float32)[None].repeat(h, 0)
    grey = 128 + 90 * np.sign(np.sin(2 * np.pi * xx / 9)) + rng.normal(0, 10, (h, w))
    grey = np.clip(cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0), 0, 255)
    grey = cv2.cvtColor(grey.astype(np.uint8), cv2.COLOR_GRAY2BGR)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return grey, gx, gy


def _post_before_a_striped_wall():
    """The scene of the thin-post tests: a striped wall (80 × 120 px, horizontal
    epipolar lines, its parallax a ramp of 0-20 px) and a red post 3 px wide at 18 px
    of parallax. Returns the reference without and the source with the post drawn
    (BGR uint8), the true matches (H, W, 2), the view and the post's slices."""
    h, w = 80, 120
    grey, gx, gy = _striped_wall(h, w, np.random.default_rng(5))
    k = 20.0 / w  # the wall: x_s = x + 20 x / W
    post = (slice(10, 70), slice(58, 61))
    src = cv2.remap(grey, gx / (1 + k), gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    src[10:70, 58 + 18:61 + 18] = _RED  # the post's parallax: 18 px
    field = np.stack([gx * (1 + k), gy], -1).astype(np.float32)
    field[post] = np.stack([gx[post] + 18, gy[post]], -1)
    F = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # x_s on row y_r
    view = TwoView(F=F, H=np.eye(3), n_matches=100, n_inliers_F=100, n_inliers_H=100,
                   parallax_px=10.0)
    return grey, src, field, view, post


_RED = (30, 30, 220)


def test_adaptive_support_finds_a_thin_post_that_the_box_window_misses():
    """A post 3 px wide stands 8 px of parallax in front of the striped wall
    behind it (horizontal epipolar lines; the wall's parallax a ramp of 0-20 px,
    10 px behind the post). The plain 5 × 5 window (10 px) compares mostly the
    wall around the post, which moves with another parallax: the post is not
    found on its line (ΔE over the search's 8). Weighted by colour likeness to
    the centre (Yoon & Kweon, 2006) it is, at its parallax. A mover pasted into
    the reference (a colour the source never shows) stays unfound either way."""
    grey, src, field, view, post = _post_before_a_striped_wall()
    h, w = grey.shape[:2]
    mover = (slice(20, 50), slice(90, 110))
    ref = grey.copy()
    ref[post] = _RED
    ref[mover] = (40, 200, 40)
    region = np.zeros((h, w), bool)
    region[post] = True
    region[mover] = True
    inner = np.zeros((h, w), bool)
    inner[15:65, 58:61] = True
    core = np.zeros((h, w), bool)
    core[25:45, 95:105] = True
    lab_r, lab_s = blurred_lab(ref, 1.0), blurred_lab(src, 1.0)
    box, _ = px.epipolar_search(lab_r, lab_s, view, field, ~region, region)
    weighted, mu = px.epipolar_search(lab_r, lab_s, view, field, ~region, region, support_de=5.0)
    assert np.median(box[inner]) > 12.0, np.median(box[inner])
    assert np.median(weighted[inner]) < 8.0, np.median(weighted[inner])
    assert np.median(np.abs(mu[inner] - 18.0)) <= 1.5, np.median(mu[inner])
    assert np.median(box[core]) > 12.0 and np.median(weighted[core]) > 12.0


def test_the_second_minimum_tells_a_plain_colour_from_a_unique_match():
    """The post of the test above is unique on its line: beyond 10 px of its match
    nothing on the line costs less than 1.5 × its cost + 2 ΔE. A plain dark patch
    in the reference (a shirt) against a source whose line runs along a plain dark
    bar (a screen) matches too, but as well 10 px and more away: its second
    minimum is as low as its best (``select_search_unique``'s ratio test)."""
    grey, src, field, view, post = _post_before_a_striped_wall()
    h, w = grey.shape[:2]
    dark = (35, 30, 30)
    shirt = (slice(25, 55), slice(15, 30))
    ref = grey.copy()
    ref[post] = _RED
    ref[shirt] = dark
    src[15:65, 10:60] = dark  # the screen: every shift of the search lands on it
    region = np.zeros((h, w), bool)
    region[post] = True
    region[shirt] = True
    lab_r, lab_s = blurred_lab(ref, 1.0), blurred_lab(src, 1.0)
    visible = ~region
    visible[15:65, 10:60] = False  # (the screen is no visible match of the wall)
    cost, mu, second = px.epipolar_search(lab_r, lab_s, view, field, visible, region,
                                          support_de=5.0, unique_px=10.0)
    inner = np.zeros((h, w), bool)
    inner[15:65, 58:61] = True
    core = np.zeros((h, w), bool)
    core[30:50, 19:26] = True
    unique = second > 1.5 * cost + 2.0
    assert np.median(cost[inner]) < 8.0 and unique[inner].mean() > 0.9
    assert np.median(cost[core]) < 8.0, np.median(cost[core])  # the shirt is "found"...
    assert not unique[core].any(), np.median(second[core])  # ... everywhere on the line
    assert np.isinf(second[~region]).all()
    # without unique_px the search returns its two maps, the same
    c2, m2 = px.epipolar_search(lab_r, lab_s, view, field, visible, region, support_de=5.0)
    np.testing.assert_array_equal(c2, cost)
    np.testing.assert_array_equal(m2, mu)


def test_the_compiled_projection_of_the_search_steps_equals_project():
    """``_project_steps`` (the epipolar search's k steps at n cells) is ``project``
    on broadcast arrays, bit for bit (a plane through the origin's column too:
    the guard against a zero third coordinate)."""
    rng = np.random.default_rng(4)
    Hm = np.eye(3) + rng.normal(0, [[0.05, 0.05, 8], [0.05, 0.05, 8], [1e-4, 1e-4, 0.01]])
    e = rng.normal(size=3)
    e /= np.linalg.norm(e)
    mu = np.linspace(-40.0, 55.0, 33)
    gx, gy = rng.uniform(-5, 860, 500), rng.uniform(-5, 485, 500)
    fx, fy = px._project_steps(Hm, e, mu, gx, gy)
    wx, wy = px.project(Hm, e, mu[:, None], gx[None], gy[None])
    np.testing.assert_array_equal(fx, wx)
    np.testing.assert_array_equal(fy, wy)


def test_the_support_weights_equal_their_first_writing():
    """``_support_weights`` (adaptive support weights of the search's windows), its
    ΔE compiled: the same values, bit for bit, as the column-by-column NumPy form it
    replaced (query cells on the crop's edge too)."""
    from dynremove.refine.colour import delta_e
    rng = np.random.default_rng(5)
    ref = rng.uniform(-60, 90, (40, 57, 3)).astype(np.float32)
    qy = np.r_[rng.integers(0, 40, 300), 0, 39, 0]
    qx = np.r_[rng.integers(0, 57, 300), 0, 56, 56]
    for box, support_de in ((5, 5.0), (3, 2.5)):
        r = box // 2
        pad = np.pad(ref, ((r, r), (r, r), (0, 0)), constant_values=np.nan)
        want = np.empty((len(qy), box * box), np.float32)
        for i, (dy, dx) in enumerate((dy, dx) for dy in range(box) for dx in range(box)):
            d = delta_e(pad[qy + dy, qx + dx], ref[qy, qx])
            want[:, i] = np.where(np.isfinite(d), np.exp(-d / support_de), 0.0)
        want = want / np.maximum(want.sum(1, keepdims=True), 1e-12)
        np.testing.assert_array_equal(px._support_weights(ref, qy, qx, box, support_de), want)


def test_the_compiled_step_costs_equal_their_numpy_form(rng):
    """``_step_costs`` writes what ``epipolar_search`` first computed in NumPy:
    min(ΔE, cap) at the cells' window positions where the step's point is in the
    source, the cap elsewhere (points off every side, and on the last pixel)."""
    from dynremove.refine.colour import delta_e
    from dynremove.refine.parallax import _CAP, _step_costs

    k, n, Hs, Ws = 7, 50, 40, 60
    fx = rng.uniform(-5, Ws + 4, (k, n)).astype(np.float32)
    fy = rng.uniform(-5, Hs + 4, (k, n)).astype(np.float32)
    fx[0, :3], fy[0, :3] = Ws - 1, Hs - 1  # on the border: inside
    smp = rng.uniform(-20, 100, (k * n, 3)).astype(np.float32)
    ref_c = rng.uniform(-20, 100, (n, 3)).astype(np.float32)
    cells = rng.choice(12 * 15, n, replace=False)
    py, px = cells // 15, cells % 15
    buf = np.full((12, 15, 32), -1.0, np.float32)
    _step_costs(smp, ref_c, fx, fy, Ws, Hs, _CAP, buf, py, px)
    inside = (fx >= 0) & (fx <= Ws - 1) & (fy >= 0) & (fy <= Hs - 1)
    d = np.minimum(delta_e(smp.reshape(k, n, 3), ref_c), _CAP)
    want = np.where(inside, d, _CAP).T
    assert inside.any() and not inside.all() and (d == _CAP).any() and (d < _CAP).any()
    assert np.array_equal(buf[py, px, :k].view(np.int32), want.astype(np.float32).view(np.int32))


def _post_near_the_camera(n_keypoints: int):
    """A striped wall 80 × 200 px (horizontal epipolar lines, x_s = x + μ, μ a ramp
    of 0-20 px: the flow's range) with a red post 8 px wide at μ = 70, nearer the
    camera than anything the flow followed, and a green patch that the source
    never shows (a mover). The flow does not follow the post (its matches there
    are the wall's). ``n_keypoints`` F-inlier keypoints at μ 68-72 lie beside the
    post (the ground at its foot), the rest on the wall. Returns (lab_r, lab_s,
    field, view, post, mover), both regions (H, W) bool."""
    h, w = 80, 200
    rng = np.random.default_rng(7)
    grey, gx, gy = _striped_wall(h, w, rng)
    k = 20.0 / w
    src = cv2.remap(grey, gx / (1 + k), gy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    ref = grey.copy()
    post = np.zeros((h, w), bool)
    post[10:70, 40:48] = True
    ref[post] = _RED
    src[10:70, 40 + 70:48 + 70] = _RED
    mover = np.zeros((h, w), bool)
    mover[20:50, 150:170] = True
    ref[mover] = (40, 200, 40)
    field = np.stack([gx * (1 + k), gy], -1).astype(np.float32)  # the wall's, everywhere
    kx = rng.uniform(0, w - 1, 60).astype(np.float32)
    ky = rng.uniform(0, h - 1, 60).astype(np.float32)
    kp_r = np.stack([kx, ky], -1)
    kp_s = np.stack([kx * (1 + k), ky], -1)
    foot = np.stack([np.linspace(30, 58, n_keypoints), np.full(n_keypoints, 74.0)], -1)
    kp_r = np.concatenate([kp_r, foot]).astype(np.float32)
    kp_s = np.concatenate([kp_s, foot + [[70.0, 0.0]] + np.linspace(-2, 2, n_keypoints)[:, None]
                           * [[1.0, 0.0]]]).astype(np.float32)
    F = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    view = TwoView(F=F, H=np.eye(3), n_matches=100, n_inliers_F=100, n_inliers_H=100,
                   parallax_px=10.0, inlier_xy_r=kp_r, inlier_xy_s=kp_s)
    return blurred_lab(ref, 1.0), blurred_lab(src, 1.0), field, view, post, mover


def test_the_search_beyond_the_flow_finds_a_post_near_the_camera():
    """The flow's range of μ (about -2 to 22) leaves out the post's 70 px of
    parallax: the plain epipolar search does not find it (the static 3-D structure
    test would call it a mover). Two keypoints beside it at μ ≈ 70 open that
    stretch of the line (``search_beyond``): the post is found there, at its μ. The
    mover, a colour the source never shows, is found on neither stretch; and a
    single keypoint (one match may lie anywhere on its line) opens nothing."""
    lab_r, lab_s, field, view, post, mover = _post_near_the_camera(2)
    region = post | mover
    visible = ~cv2.dilate(region.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    lo, hi = px.flow_mu_range(view, field, visible)
    assert -5 < lo < 0 and 20 < hi < 26, (lo, hi)
    inner = np.zeros_like(post)
    inner[15:65, 42:46] = True
    core = np.zeros_like(mover)
    core[25:45, 155:165] = True
    cost, _ = px.epipolar_search(lab_r, lab_s, view, field, visible, region, support_de=5.0)
    assert np.median(cost[inner]) > 12.0, np.median(cost[inner])
    c_far, mu_far = px.search_beyond(lab_r, lab_s, view, field, visible, region, ring_px=40,
                                     support_de=5.0)
    assert np.median(c_far[inner]) < 8.0, np.median(c_far[inner])
    assert np.median(np.abs(mu_far[inner] - 70.0)) <= 2.0, np.median(mu_far[inner])
    assert (mu_far[post & np.isfinite(mu_far)] > hi).all()  # only beyond the flow's range
    # the mover is beyond the keypoints' ring: not searched there; nor anywhere off L
    assert np.isinf(c_far[mover]).all() and np.isinf(c_far[~region]).all()
    # with the ring over the mover too, it is still not found
    c_all, _ = px.search_beyond(lab_r, lab_s, view, field, visible, region, ring_px=150,
                                support_de=5.0)
    assert np.median(c_all[core]) > 12.0, np.median(c_all[core])
    # one keypoint beyond the range opens no stretch
    lab_r, lab_s, field, view, post, mover = _post_near_the_camera(1)
    c_one, _ = px.search_beyond(lab_r, lab_s, view, field, visible, region, ring_px=40,
                                support_de=5.0)
    assert np.isinf(c_one).all()
    # nor do keypoints without F
    no_f = TwoView(F=None, H=np.eye(3), n_matches=0, n_inliers_F=0, n_inliers_H=0)
    assert np.isinf(px.search_beyond(lab_r, lab_s, no_f, field, visible, region,
                                     ring_px=40)[0]).all()


def test_keypoint_windows_need_two_keypoints_that_agree():
    """``keypoint_windows``: a window around each keypoint's μ beyond the flow's
    range [0, 20], ± max(4, 10 % of its distance from the range), counted where
    two keypoints share it; overlapping windows merge."""
    assert px.keypoint_windows(np.array([70.0]), 0.0, 20.0) == []  # one alone: none
    assert px.keypoint_windows(np.array([70.0, 90.0]), 0.0, 20.0) == []  # apart: none
    (a, b), = px.keypoint_windows(np.array([70.0, 73.0]), 0.0, 20.0)
    assert a == pytest.approx(70.0 - 5.0) and b == pytest.approx(73.0 + 5.3)
    # below the range, and near it the floor of 4
    (a, b), = px.keypoint_windows(np.array([-3.0, -1.0]), 0.0, 20.0)
    assert a == pytest.approx(-7.0) and b == pytest.approx(3.0)
    # two pairs far apart: two windows, in order; with three keypoints required,
    # only the triple's
    mu = np.array([300.0, 30.0, 305.0, 33.0, 310.0])
    w = px.keypoint_windows(mu, 0.0, 20.0)
    assert len(w) == 2 and w[0][1] < w[1][0] and w[0][0] < 30.0 < 33.0 < w[0][1]
    (a, b), = px.keypoint_windows(mu, 0.0, 20.0, min_keypoints=3)
    assert a < 300.0 and b > 310.0
