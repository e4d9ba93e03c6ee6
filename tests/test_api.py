"""The Python API as a library user calls it (a fresh-user trial of it, session 66).

``remove_dynamic`` takes the ImageSet that ``load_image_set`` reads, with its
validity masks and notes; ``load_image_set`` takes a folder as a str or Path and any
iterable of paths; a run that would not fit in memory, a process forked after a
run (numba's OpenMP layer), a sink or progress of the wrong kind: each one clear
error before any work. The result prints as a summary.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynremove import io, pipeline
from dynremove.errors import InputError
from dynremove.evaluation import synth
from dynremove.pipeline import remove_dynamic

REPO = Path(__file__).resolve().parents[1]


def _bordered_set(folder: Path) -> Path:
    """A synthetic set whose view 1 was shifted 12 px, its left edge black (no
    content), as a pre-aligned frame or a stitched photo has."""
    scene = synth.make_scene(seed=1, n_views=4, size=(96, 128))
    folder.mkdir(parents=True)
    for i, (name, im) in enumerate(zip(scene.names, scene.images)):
        if i == 1:
            im = np.concatenate([np.zeros((96, 12, 3), np.uint8), im[:, :-12]], axis=1)
        assert cv2.imwrite(str(folder / name), im)
    return folder


def test_an_image_set_is_taken_whole(tmp_path):
    """``remove_dynamic(load_image_set(...))`` is the command line's reading: the
    set's names, validity masks and notes come with it. The trial's recipe,
    ``remove_dynamic(s.images, names=s.names)``, dropped the masks: a black border
    (here 12 px of view 1) then differs from what the command line writes."""
    iset = io.load_image_set([_bordered_set(tmp_path / "set")])
    assert iset.valid_masks is not None and any("without content" in n or "border" in n
                                                 for n in iset.notes), iset.notes
    whole = remove_dynamic(iset)
    explicit = remove_dynamic(iset.images, names=iset.names, valid_masks=iset.valid_masks)
    np.testing.assert_array_equal(whole.clean, explicit.clean)
    np.testing.assert_array_equal(whole.dynamic, explicit.dynamic)
    assert all(n in whole.warnings for n in iset.notes)
    # names given in the call win over the set's
    named = remove_dynamic(iset, names=[f"p{i}" for i in range(4)], ref="p1")
    assert named.ref_index == 1


def test_load_image_set_takes_a_folder_as_str_or_path_and_any_iterable(tmp_path):
    folder = _bordered_set(tmp_path / "set")
    want = io.load_image_set([folder]).names
    assert io.load_image_set(str(folder)).names == want  # (was read letter by letter)
    assert io.load_image_set(folder).names == want
    assert io.load_image_set(p for p in sorted(folder.iterdir())).names == want
    with pytest.raises(InputError, match=r"max_side='1280': give an int"):
        io.load_image_set(folder, max_side="1280")
    with pytest.raises(InputError, match="not int"):
        io.load_image_set(5)


def test_a_run_that_would_not_fit_in_memory_is_refused_first(monkeypatch):
    """Full-size phone photos given as arrays: the command line's memory check, in
    one InputError before any work (a trial's MemoryError after 20 s, or the
    OOM killer taking the notebook with it)."""
    scene = synth.make_scene(seed=0, n_views=3, size=(96, 128))
    monkeypatch.setattr(pipeline, "physical_memory", lambda: 0.2e9)
    with pytest.raises(InputError, match=r"needs about 0 GB of memory, more than this "
                                         r"machine's 0 GB: read them with dynremove\.io\."
                                         r"load_image_set\(paths, max_side=1280\)"):
        remove_dynamic(scene.images, sink=_Exploding())


class _Exploding:
    """A sink that fails the test if the run got as far as using it."""

    enabled = True

    def __getattr__(self, name):
        raise AssertionError(f"the run started: sink.{name}")


@pytest.mark.parametrize("kw,words", [
    ({"sink": 5}, "sink=int: an EventSink is needed (it lacks enabled, start"),
    ({"progress": 5}, "progress=5: give a callable"),
])
def test_a_sink_or_progress_of_the_wrong_kind_is_one_input_error(kw, words):
    scene = synth.make_scene(seed=0, n_views=3, size=(96, 128))
    with pytest.raises(InputError) as e:
        remove_dynamic(scene.images, **kw)
    assert words in str(e.value), e.value


def test_the_result_prints_as_a_summary():
    """``repr`` of a Result was 66 000 characters of arrays (a notebook cell flooded)."""
    scene = synth.make_scene(seed=0, n_views=4, size=(96, 128))
    res = remove_dynamic(scene.images)
    text = repr(res)
    assert len(text) < 200 and text.startswith("Result(128x96, reference 2, sources [0, 1, 3]")
    assert f"{100 * res.dynamic.mean():.1f} % dynamic" in text
    assert res == res and res != remove_dynamic(scene.images)  # identity, no array ==


_FORK = textwrap.dedent("""
    import multiprocessing as mp, numba
    from dynremove.evaluation import synth
    from dynremove.pipeline import remove_dynamic

    def job(seed):
        scene = synth.make_scene(seed=seed, n_views=3, size=(64, 96))
        return int(remove_dynamic(scene.images).dynamic.sum())

    if __name__ == "__main__":
        job(0)  # the parent runs first (a notebook's warm-up call)
        print("layer", numba.threading_layer(), flush=True)
        with mp.get_context("fork").Pool(1) as pool:
            try:
                print("ok", pool.map(job, [0]), flush=True)
            except RuntimeError as e:
                print("refused", e, flush=True)
""")


@pytest.mark.skipif(sys.platform != "linux", reason="fork is the default start method on Linux")
def test_a_pool_forked_after_a_run_gets_an_error_not_a_hang(tmp_path):
    """numba's OpenMP layer (GNU libgomp) is not fork-safe: a worker forked after the
    parent ran dynremove was terminated by numba at its first parallel kernel, and
    ``Pool.map`` waited forever (a fresh-user trial, 900 s). The worker now raises
    a RuntimeError that says to use "spawn" or "forkserver", which the pool hands
    back. (Where numba's layer is another, forking works and the job runs.)"""
    script = tmp_path / "fork_after_run.py"
    script.write_text(_FORK)
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                       cwd=REPO, timeout=180)
    lines = p.stdout.splitlines()
    assert p.returncode == 0 and lines and lines[0].startswith("layer "), (p.stdout, p.stderr)
    if lines[0] == "layer omp":
        assert lines[1].startswith("refused this process was forked from one that had "
                                   "already run dynremove"), p.stdout
        assert "get_context('spawn')" in lines[1] and "Terminating" not in p.stderr
    else:
        assert lines[1].startswith("ok ["), (p.stdout, p.stderr)


def test_the_notes_are_warnings_of_their_own_category():
    """A caller can filter the run's notes (they were plain UserWarnings) and still
    read them in ``Result.warnings``."""
    import warnings

    import dynremove

    scene = synth.make_scene(seed=0, n_views=4, size=(48, 64))  # few matches: notes
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = remove_dynamic(scene.images)
    notes = [w for w in caught if issubclass(w.category, dynremove.Note)]
    assert res.warnings and [str(w.message) for w in notes] == res.warnings
    assert issubclass(dynremove.Note, UserWarning)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warnings.simplefilter("ignore", dynremove.Note)
        again = remove_dynamic(scene.images)
    assert not caught and again.warnings == res.warnings


def test_params_and_presets_reject_with_the_inputerror_the_readme_names():
    """The README says bad input raises InputError; Params and preset raised a plain
    ValueError, which ``except InputError`` missed (it stays a ValueError)."""
    from dynremove import Params, preset

    for bad in (lambda: Params(select_tau=-1), lambda: preset("x")):
        with pytest.raises(InputError):
            bad()
    assert issubclass(InputError, ValueError)


def test_a_mistyped_parameter_name_is_an_inputerror_naming_the_closest():
    """``Params(select_tua=5)`` raised Python's TypeError (a left-over of session 66's
    API trial); both ways of making a variant now raise InputError with the name
    meant, and a right name still works."""
    from dynremove import Params, preset

    for bad in (lambda: Params(select_tua=5.0), lambda: preset("default").replace(select_tua=5.0)):
        with pytest.raises(InputError, match="no field 'select_tua'; did you mean select_tau"):
            bad()
    with pytest.raises(InputError, match="no field 'zzz'; help"):
        Params(zzz=1)
    assert Params(select_tau=5.0).select_tau == 5.0
    assert preset("paper").replace(t_r=0.5).t_r == 0.5
    with pytest.raises(TypeError):  # positional arguments stay refused (kw_only)
        Params(13)


def test_help_on_params_names_every_field():
    """``help(Params)`` lists each field with its default and meaning (the CLI's help
    text), where it gave the class's two sentences only."""
    import dataclasses

    from dynremove import PAPER, Params

    doc = Params.__doc__
    for f in dataclasses.fields(Params):
        assert f"    {f.name} : " in doc, f.name
    assert "patch_size : int, default 13 (paper 9)" in doc and PAPER.patch_size == 9
