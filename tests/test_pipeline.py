"""End to end on synthetic scenes with ground truth, and the CLI."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dynremove import MemorySink, NullSink, preset, remove_dynamic
from dynremove.evaluation import synth
from dynremove.cli import main
from dynremove.evaluation.metrics import jaccard, psnr_in_mask


@pytest.fixture(scope="module")
def scene():
    return synth.make_scene(seed=0, n_views=6, size=(360, 640))


@pytest.fixture(scope="module")
def result(scene):
    return remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"))


def test_default_detects_and_removes(scene, result):
    """The demo scene (`dynremove demo`).

    Issue 2's floor was J >= 0.9 and 30 dB inside the mask, met by the median of
    all sources (31.4 dB). The fill by selection (issue 10) copies the free
    sources that agree with the chosen one instead: 29.4 dB here, for no ghost
    and no damage on sparse and parallax sets (README "Fill by selection").
    """
    gt = scene.masks[scene.ref_index]
    assert jaccard(result.dynamic, gt) >= 0.9
    assert psnr_in_mask(result.clean, scene.background, gt) >= 29.0
    # the whole photo: nothing that was right in the reference is damaged
    lab = [cv2.cvtColor(cv2.GaussianBlur(im, (0, 0), 1.0).astype(np.float32) / 255,
                        cv2.COLOR_BGR2Lab) for im in (scene.images[scene.ref_index],
                                                     result.clean, scene.background)]
    right_in = np.linalg.norm(lab[0] - lab[2], axis=-1) <= 10
    wrong_out = np.linalg.norm(lab[1] - lab[2], axis=-1) > 10
    outside = ~cv2.dilate(gt.astype(np.uint8), np.ones((11, 11), np.uint8)).astype(bool)
    assert (outside & right_in & wrong_out).mean() <= 0.005
    before = psnr_in_mask(scene.images[scene.ref_index], scene.background, gt)
    assert before < 12.0


def test_sinks_do_not_change_results(scene, result):
    mem = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                         sink=MemorySink(), sample_static=0.01)
    null = remove_dynamic(scene.images, ref=scene.ref_index, params=preset("default"),
                          sink=NullSink())
    for r in (mem, null):
        np.testing.assert_array_equal(r.clean, result.clean)
        np.testing.assert_array_equal(r.dynamic, result.dynamic)


def test_identical_images_change_nothing(scene):
    ims = [scene.background.copy() for _ in range(4)]
    for name in ("paper", "default"):
        r = remove_dynamic(ims, ref=1, params=preset(name))
        assert not r.dynamic.any()
        np.testing.assert_array_equal(r.clean, ims[1])


def test_cli_run_end_to_end(tmp_path, scene):
    synth.write_scene(scene, tmp_path / "set")
    out = tmp_path / "out"
    code = main(["run", str(tmp_path / "set" / "frames"), "--out", str(out), "--quiet",
                 "--gt", str(tmp_path / "set" / "masks" / scene.names[scene.ref_index])])
    assert code == 0
    mask = cv2.imread(str(out / "dynamic_mask.png"), cv2.IMREAD_UNCHANGED)
    clean = cv2.imread(str(out / "clean.png"))
    assert mask.dtype == np.uint8 and mask.shape == scene.masks[0].shape
    assert set(np.unique(mask)) <= {0, 255}
    assert clean.shape == scene.images[0].shape
    rep = json.loads((out / "report.json").read_text())
    assert rep["reference"]["index"] == scene.ref_index
    assert rep["scans"] and all(k in rep["seconds"] for k in ("features", "scans", "total"))
    assert rep["jaccard_vs_gt"] == pytest.approx(jaccard(mask > 0, scene.masks[scene.ref_index]))
    assert not list(out.glob("*.tmp"))


def test_cli_bad_input_exit_code(tmp_path, capsys):
    (tmp_path / "a.png").write_bytes(b"")
    code = main(["run", str(tmp_path / "a.png"), "--out", str(tmp_path / "o")])
    assert code == 2
    err = capsys.readouterr().err
    assert "need at least 2 images" in err and "Traceback" not in err


def test_default_on_other_synthetic_scenes():
    """Not just the demo's seed: seeds 1-3 (measured J .889/.929/.931, 28.1/31.0/29.1 dB)."""
    js, ps = [], []
    for seed in (1, 2, 3):
        sc = synth.make_scene(seed=seed, n_views=6, size=(360, 640))
        r = remove_dynamic(sc.images, ref=sc.ref_index, params=preset("default"))
        gt = sc.masks[sc.ref_index]
        js.append(jaccard(r.dynamic, gt))
        ps.append(psnr_in_mask(r.clean, sc.background, gt))
    assert min(js) >= 0.8 and np.mean(js) >= 0.88
    assert min(ps) >= 25.0 and np.mean(ps) >= 28.5
