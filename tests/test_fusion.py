"""Field interpolation, fusion and the border refinement, on known ground truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dynremove import preset
from dynremove.evaluation import synth
from dynremove.refine import fields, fill, mask, morphology
from dynremove.evaluation.metrics import jaccard, psnr_in_mask


def _disc_hole(H, W, cx, cy, r):
    ys, xs = np.mgrid[0:H, 0:W]
    return (xs - cx) ** 2 + (ys - cy) ** 2 <= r * r


def test_harmonic_fill_reproduces_a_linear_field():
    H, W = 120, 160
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    field = np.stack([0.03 * xs - 0.02 * ys + 4.0, 0.01 * xs + 0.05 * ys - 1.0], -1)
    hole = _disc_hole(H, W, 70, 60, 30) | _disc_hole(H, W, 130, 30, 12)
    broken = field.copy()
    broken[hole] = 1e3  # garbage under the hole must not leak out
    out = fields.harmonic_fill(broken, hole)
    np.testing.assert_array_equal(out[~hole], field[~hole])  # valid pixels untouched
    assert np.abs(out[hole] - field[hole]).max() < 0.1  # a plane is a membrane
    # the quick Gaussian interpolation is biased on the same field
    gauss = fields.interpolate_field(broken, hole)
    assert np.abs(gauss[hole] - field[hole]).max() > 5 * np.abs(out[hole] - field[hole]).max()


def test_harmonic_fill_edge_cases():
    f = np.ones((30, 40, 2), np.float32)
    np.testing.assert_array_equal(fields.harmonic_fill(f, np.zeros((30, 40), bool)), f)
    np.testing.assert_array_equal(fields.harmonic_fill(f, np.ones((30, 40), bool)), f)
    tiny = np.zeros((8, 8), bool)
    tiny[3:5, 3:5] = True
    np.testing.assert_allclose(fields.harmonic_fill(np.ones((8, 8, 1), np.float32), tiny), 1.0)


def test_the_sources_fields_solved_together_equal_one_at_a_time():
    """``background_fields`` solves S fields as one field of 2·S channels: the
    same values, bit for bit, as S solves (holes at the frame's edge too)."""
    rng = np.random.default_rng(1)
    H, W = 90, 140
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    Nf = [np.stack([xs + 3 * k + rng.normal(size=(H, W)).astype(np.float32),
                    ys - k + rng.normal(size=(H, W)).astype(np.float32)], -1) for k in range(5)]
    hole = _disc_hole(H, W, 60, 45, 25) | _disc_hole(H, W, 135, 10, 15)
    hole[85:, :30] = True
    together = fields.background_fields(Nf, hole)
    for f, t in zip(Nf, together):
        one = fields.harmonic_fill(f - np.stack([xs, ys], -1), hole) + np.stack([xs, ys], -1)
        np.testing.assert_array_equal(t, one)
        np.testing.assert_allclose(t[~hole], f[~hole], rtol=0, atol=1e-4)  # (f - x) + x
    assert fields.background_fields([], hole) == []


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=1, n_views=5, size=(180, 320))


def _true_fields(scene):
    srcs = [v for v in range(len(scene.images)) if v != scene.ref_index]
    Nf = np.stack([synth.reference_flow(scene, v) for v in srcs]).astype(np.float32)
    return np.stack([scene.images[v] for v in srcs]), Nf


def test_fuse_with_true_matches_restores_the_background(scene):
    sources, Nf = _true_fields(scene)
    ref = scene.images[scene.ref_index]
    gt = scene.masks[scene.ref_index]
    clean, n_valid = fill.fuse_background(ref, sources, Nf, gt)
    assert psnr_in_mask(clean, scene.background, gt) > 26.0  # input: ~10 dB
    assert psnr_in_mask(ref, scene.background, gt) < 15.0
    outside = ~morphology.dilate_disc(gt, 2)
    np.testing.assert_array_equal(clean[outside], ref[outside])  # only the region is written
    assert (n_valid[gt] == len(sources)).mean() > 0.9


def test_fuse_rejects_bad_arguments(scene):
    sources, Nf = _true_fields(scene)
    ref = scene.images[scene.ref_index]
    gt = scene.masks[scene.ref_index]
    with pytest.raises(ValueError, match="combine"):
        fill.fuse_background(ref, sources, Nf, gt, combine="mean")
    with pytest.raises(ValueError, match="homographies"):
        fill.fuse_background(ref, sources, Nf, gt, realign=1)
    empty = np.zeros_like(gt)
    np.testing.assert_array_equal(fill.fuse_background(ref, sources, Nf, empty)[0], ref)


def test_source_votes_separate_object_from_background(scene):
    sources, Nf = _true_fields(scene)
    ref = scene.images[scene.ref_index]
    gt = scene.masks[scene.ref_index]
    D = fields.source_votes(ref, sources, Nf, np.zeros_like(gt))
    agree = (D < 16.0).sum(0)
    # background pixels: nearly every source agrees; object pixels: nearly none
    assert np.median(agree[~gt]) == len(sources)
    assert np.median(agree[gt]) <= 1


def test_refine_mask_fixes_a_too_wide_and_a_too_narrow_map(scene):
    sources, Nf = _true_fields(scene)
    ref = scene.images[scene.ref_index]
    gt = scene.masks[scene.ref_index]
    params = preset("default")
    wide = morphology.dilate_disc(gt, 3)  # the p/2 halo of the scan
    refined = mask.refine_mask(ref, sources, Nf, wide, params)
    assert jaccard(refined, gt) > jaccard(wide, gt) + 0.05
    # a map that stops short of the object's outline grows back
    cut = gt & ~morphology.dilate_disc(~gt, 4)
    regrown = mask.refine_mask(ref, sources, Nf, cut, params)
    assert jaccard(regrown, gt) > jaccard(cut, gt) + 0.03
    # nothing far from the map changes
    far = ~morphology.dilate_disc(wide, params.refine_ring_px * params.refine_iters + 2)
    assert not refined[far].any()


def test_snap_to_edges_moves_the_border_onto_the_object():
    rng = np.random.default_rng(0)
    H, W = 120, 160
    img = np.clip(rng.normal(90, 12, (H, W, 3)), 0, 255).astype(np.uint8)  # grey grain
    obj = _disc_hole(H, W, 60, 60, 25) | _disc_hole(H, W, 115, 70, 15)
    img[obj] = np.clip(rng.normal((40, 60, 200), 12, (int(obj.sum()), 3)), 0, 255)
    params = preset("default")
    for start in (morphology.dilate_disc(obj, 5), obj & ~morphology.dilate_disc(~obj, 4)):
        snapped = mask.snap_to_edges(img, start, params)
        assert jaccard(start, obj) < 0.85
        assert jaccard(snapped, obj) > 0.95
    empty = np.zeros((H, W), bool)
    assert not mask.snap_to_edges(img, empty, params).any()


def test_snap_to_edges_does_not_depend_on_what_drew_from_opencvs_rng_before():
    """GrabCut's k-means draws from OpenCV's RNG of the calling thread: the cut must
    not depend on what ran before it (the geometry's seeding, on whichever thread it
    ran). Noisy colours that overlap, where the colour models' start matters (before
    the fix: 183 and 37 px differed after two other RNG states)."""
    rng = np.random.default_rng(3)
    H, W = 120, 160
    img = np.clip(rng.normal(110, 45, (H, W, 3)), 0, 255).astype(np.uint8)
    obj = _disc_hole(H, W, 60, 60, 25) | _disc_hole(H, W, 115, 70, 15)
    img[obj] = np.clip(rng.normal((90, 100, 150), 45, (int(obj.sum()), 3)), 0, 255)
    params = preset("default")
    start = morphology.dilate_disc(obj, 6)
    cuts = []
    for seed in (0, 2, 99):
        cv2.setRNGSeed(seed)
        cv2.randu(np.zeros(5), 0, 1)
        cuts.append(mask.snap_to_edges(img, start, params))
    for cut in cuts[1:]:
        np.testing.assert_array_equal(cut, cuts[0])


def test_veto_agreed_drops_static_growth_and_keeps_the_object(scene):
    """The snap's growth is vetoed where the sources agree with the reference (a
    false positive in the static scene, grown) and kept where they do not (the
    object)."""
    sources, Nf = _true_fields(scene)
    ref = scene.images[scene.ref_index]
    gt = scene.masks[scene.ref_index]
    params = preset("default")
    # a static patch flagged by mistake, as far as can be from every view's mover
    movers = np.any(np.stack(scene.masks), axis=0)
    dist = cv2.distanceTransform((~movers).astype(np.uint8), cv2.DIST_L2, 5)
    dist[:20], dist[-20:], dist[:, :20], dist[:, -20:] = 0, 0, 0, 0
    cy, cx = np.unravel_index(np.argmax(dist), dist.shape)
    assert dist[cy, cx] > 25, "the scene has room for it"
    H, W = gt.shape
    fp = _disc_hole(H, W, cx, cy, 8)
    before = gt | fp
    grown = before | morphology.dilate_disc(fp, 6)
    kept = mask.veto_agreed(ref, sources, Nf, before, grown, params)
    added = grown & ~before
    np.testing.assert_array_equal(kept & before, before)  # the map it started from stays
    assert (kept & added).sum() < 0.1 * added.sum()
    # a map that stopped 4 px short of the object's outline, grown back onto it: kept
    cut = gt & ~morphology.dilate_disc(~gt, 4)
    regrown = mask.veto_agreed(ref, sources, Nf, cut, gt, params)
    assert (regrown & gt & ~cut).sum() > 0.9 * (gt & ~cut).sum()
    assert not (regrown & ~gt).any()
    # nothing added: nothing to veto
    np.testing.assert_array_equal(mask.veto_agreed(ref, sources, Nf, gt, gt, params), gt)


def test_the_median_fill_leaves_out_the_samples_it_is_told_show_a_mover():
    """``median_fill(exclude=…)``: the re-alignment's target (``select_fill``) must
    not take in a source's copy of a lingering mover. Three sources, identity
    fields: two show gray backgrounds (60, 90), one a red mover. Unmasked, the
    per-channel median takes the red in; with the mover's source excluded it is
    the two grays' mean; with all three excluded, the reference stays."""
    H, W = 20, 30
    ref = np.full((H, W, 3), 200, np.uint8)
    srcs = np.stack([np.full((H, W, 3), 60, np.uint8), np.full((H, W, 3), 90, np.uint8),
                     np.full((H, W, 3), (0, 0, 255), np.uint8)])
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    flds = [np.stack([xs, ys], -1)] * 3
    region = np.zeros((H, W), bool)
    region[5:15, 5:25] = True
    plain, n = fill.median_fill(ref, srcs, flds, region)
    # per channel: median(60, 90, 0), median(60, 90, 0), median(60, 90, 255)
    assert (plain[region] == (60, 60, 90)).all() and (n[region] == 3).all()
    exclude = np.zeros((3, H, W), bool)
    exclude[2, 5:15, 5:15] = True  # the mover's source, over the left half
    out, n = fill.median_fill(ref, srcs, flds, region, exclude=exclude)
    left, right = region.copy(), region.copy()
    left[:, 15:], right[:, :15] = False, False
    assert (out[left] == 75).all() and (n[left] == 2).all()  # (60 + 90) / 2, no red
    assert (out[right] == (60, 60, 90)).all()
    exclude[:, 5:15, 5:10] = True  # nobody may fill: the reference is kept
    out, n = fill.median_fill(ref, srcs, flds, region, exclude=exclude)
    assert (out[5:15, 5:10] == 200).all() and (n[5:15, 5:10] == 0).all()
    np.testing.assert_array_equal(out[~region], ref[~region])
