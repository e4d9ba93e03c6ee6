"""Interrupted runs keep a readable recording (issue 12, item 5).

The CLI is run in a subprocess with ``--record`` and sent SIGINT (a) as soon as
the recording file exists (features / correspondences, before the scans) and
(b) during the scan. The recording must end with an "interrupted ..." log entry
and ``dynremove inspect`` must read it: exit 0 or 2, one-line messages, never a
traceback or "internal error".
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader  # noqa: E402

from dynremove.evaluation import synth  # noqa: E402
from viewer import inspect as vi  # noqa: E402
from viewer.sink import RerunSink  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "DYNREMOVE_DEBUG": "", "PYTHONUNBUFFERED": "1"}


def _write_set(folder: Path, size: tuple[int, int]) -> Path:
    scene = synth.make_scene(seed=0, n_views=4, size=size)
    folder.mkdir(parents=True, exist_ok=True)
    for name, im in zip(scene.names, scene.images):
        cv2.imwrite(str(folder / name), im)
    return folder


def _store(path: Path):
    return RrdReader(str(path)).stream().collect()


def _log_texts(path: Path) -> list[str]:
    cs = _store(path)
    t = cs.reader(index="step", contents="/log").to_arrow_table()
    return [x for v in t.column("/log:TextLog:text").to_pylist() if v for x in v]


def _sigint_default() -> None:
    """In the child before exec: SIGINT as a terminal gives it. A test run started in
    the background of a non-interactive shell inherits SIGINT ignored, and the run
    would then (rightly) not stop."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(images: Path, tmp: Path, rrd: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "dynremove.cli", "run", str(images), "--out", str(tmp / "out"),
         "--record", str(rrd), *extra],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=ENV,
        preexec_fn=_sigint_default)


def _interrupt(p: subprocess.Popen) -> tuple[int, str]:
    p.send_signal(signal.SIGINT)
    try:
        _, err = p.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        p.kill()
        p.communicate()
        pytest.fail("the run did not stop within 30 s of SIGINT")
    return p.returncode, err


def _inspect(rrd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dynremove.cli", "inspect", str(rrd), *args],
                          capture_output=True, text=True, cwd=REPO, env=ENV, timeout=60)


def _clean_lines(stderr: str) -> list[str]:
    assert "Traceback" not in stderr and "internal error" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip()
             and not re.match(r"^\S.* \[[#-]+\] +[\d.]+ % +[\d.]+ s$", ln)]  # progress
    assert all(ln.startswith("dynremove: ") for ln in lines), stderr
    return lines


def test_ctrl_c_before_the_scans_keeps_a_readable_recording(tmp_path):
    images = _write_set(tmp_path / "set", (120, 160))
    rrd = tmp_path / "run.rrd"
    p = _start(images, tmp_path, rrd)
    t0 = time.monotonic()
    while not rrd.exists():  # the sink opens the file before the features
        if p.poll() is not None or time.monotonic() - t0 > 60:
            p.kill()
            pytest.fail(f"no recording appeared (exit {p.poll()}): {p.communicate()[1]}")
        time.sleep(0.005)
    rc, err = _interrupt(p)
    assert rc == 130, err
    assert "Traceback" not in err
    # what is left, said (a fresh-user trial: "interrupted" alone did not say)
    assert "nothing was written to" in err and f"cut short, is {rrd}" in err, err
    texts = _log_texts(rrd)
    last = [t for t in texts if t.startswith("interrupted")]
    assert last, texts  # normally "before the scans began"; a slow signal may land later
    msg = vi.interruption(_store(rrd))
    assert msg == last[-1]
    r = _inspect(rrd, "--failures")
    assert r.returncode in (0, 2), r.stderr
    lines = _clean_lines(r.stderr)
    assert len(lines) <= 2 and "interrupted" in lines[0], r.stderr


def test_ctrl_c_during_the_scan_says_where_it_ends(tmp_path):
    images = _write_set(tmp_path / "set", (240, 320))
    msg = None
    # retried only if the signal missed the scan, or came before its first row was
    # recorded (step 0: nothing to inspect, a right answer; seen under load), or
    # before the scan began (under a load average of 6, 0.8 s after the similarity
    # line was still before it; with two evals beside a CI run, 2 s was too)
    for delay in (0.3, 0.8, 2.0, 4.0, 8.0, 0.05):
        rrd = tmp_path / f"run_{delay}.rrd"
        p = _start(images, tmp_path, rrd, "--record-every-rows", "1")
        for line in p.stderr:  # non-tty progress: one line when a stage completes
            if line.startswith("similarity"):  # the last stage before the scans
                break
        time.sleep(delay)
        rc, err = _interrupt(p)
        # finished before the signal: try an earlier one (a signal that lands after
        # the command returned, while Python shuts down, kills it with SIGINT: -2)
        if rc == 0 or (rc == -signal.SIGINT and "writing" in err):
            continue
        assert rc == 130, err
        texts = _log_texts(rrd)
        assert any(t.startswith("interrupted") for t in texts), texts
        msg = vi.interruption(_store(rrd))
        if msg and msg.startswith("interrupted at scan") and not msg.endswith(" step 0"):
            break
    assert msg is not None and msg.startswith("interrupted at scan 0, step "), msg
    step = int(msg.rsplit(" ", 1)[1])
    assert 0 <= step < 240 * 320 * 4
    assert texts[-1] == msg  # the last entry of the log

    r = _inspect(rrd, "--pixel", "5,5")
    assert r.returncode == 0, r.stderr
    assert _clean_lines(r.stderr) == [
        f"dynremove: note: {rrd.resolve()}: the run was {msg}: read what was recorded"]
    r = _inspect(rrd, "--failures")  # needs a finished run: exit 2, one line of error
    assert r.returncode == 2, r.stderr
    lines = _clean_lines(r.stderr)
    assert [ln for ln in lines if "error" in ln] == [lines[-1]] and "did not finish" in lines[-1]
    gif = tmp_path / "run.gif"
    r = subprocess.run([sys.executable, "-m", "dynremove.cli", "export", str(rrd),
                        "--out", str(gif)], capture_output=True, text=True, cwd=REPO,
                       env=ENV, timeout=60)
    assert r.returncode == 0, r.stderr
    lines = _clean_lines(r.stderr)  # that the run was cut (read while choosing the run,
    # before any drawing), then what export is doing
    assert len(lines) == 2 and "drawing a frame per snapshot" in lines[1], r.stderr
    assert "the run was interrupted" in lines[0] and gif.stat().st_size > 0


def test_sink_interrupted_before_start(tmp_path):
    """In process: begin() then interrupted(): names, size and reference recorded."""
    rrd = tmp_path / "early.rrd"
    sink = RerunSink(rrd)
    ims = [np.full((40, 60, 3), 10 * i, np.uint8) for i in range(3)]
    sink.begin(["a.png", "b.png", "c.png"], (40, 60), images=ims, ref=1)
    sink.interrupted()
    sink.close()  # idempotent, as the CLI calls it again
    assert _log_texts(rrd)[-1] == "interrupted before the scans began"
    store = _store(rrd)
    assert vi.interruption(store) == "interrupted before the scans began"
    info = vi._static_values(store, "/run/info")
    assert info["names"] == ["a.png", "b.png", "c.png"] and info["height"] == [40]
    with pytest.raises(vi.InputError, match="interrupted before the scans began"):
        vi.load_store(rrd)

    # interrupted before begin(): the file still exists with the entry
    rrd2 = tmp_path / "none.rrd"
    RerunSink(rrd2).interrupted()
    assert _log_texts(rrd2) == ["interrupted before the scans began"]


def test_a_cut_run_keeps_the_earlier_recording_at_its_path(tmp_path):
    """A fresh-user trial: ``run --record keep.rrd`` over a good recording, cut
    short, left a partial one in its place. The earlier file is kept; the cut run's
    is ``keep.partial.rrd`` beside it, and no temporary file is left. A whole run
    replaces the earlier file."""
    rrd = tmp_path / "keep.rrd"
    rrd.write_bytes(b"an earlier recording")
    ims = [np.full((40, 60, 3), 10 * i, np.uint8) for i in range(3)]
    sink = RerunSink(rrd)
    sink.begin(["a.png", "b.png", "c.png"], (40, 60), images=ims, ref=1)
    sink.interrupted()
    assert rrd.read_bytes() == b"an earlier recording"
    assert sink.partial_path == tmp_path / "keep.partial.rrd"
    assert _log_texts(sink.partial_path)[-1] == "interrupted before the scans began"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.partial.rrd", "keep.rrd"]

    import warnings

    from dynremove.pipeline import remove_dynamic

    scene = synth.make_scene(seed=0, n_views=3, size=(60, 96))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the run's notes)
        remove_dynamic(scene.images, ref=scene.ref_index, sink=RerunSink(rrd))
    assert rrd.read_bytes() != b"an earlier recording" and vi.load_store(rrd) is not None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.partial.rrd", "keep.rrd"]


# --- before the sink exists: loading, reference, opening the recording ---------------------
def _wait_for_main(p: subprocess.Popen, timeout: float = 120) -> None:
    """Until ``dynremove.cli.main`` runs: it installs the SIGTERM handler (Linux:
    /proc/PID/status SigCgt), i.e. the imports are done and the run begins."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        try:
            status = Path(f"/proc/{p.pid}/status").read_text()
        except OSError:
            break
        caught = int(status.split("SigCgt:")[1].split()[0], 16)
        if caught >> (signal.SIGTERM - 1) & 1:
            return
        time.sleep(0.001)
    p.kill()
    pytest.fail(f"the run did not reach main() (exit {p.poll()}): {p.communicate()[1]}")


def _readable_or_none(rrd: Path, err: str, rc: int) -> str | None:
    """Exit 130 with one line; the recording, if any, ends with "interrupted ..." and
    ``inspect`` reads it (exit 0, or 2 when nothing was recorded to inspect)."""
    assert rc == 130, err
    lines = _clean_lines(err)
    assert lines[-1] == "dynremove: interrupted", err
    assert not [ln for ln in lines if "error" in ln], err
    if not rrd.exists():
        return None
    texts = _log_texts(rrd)
    assert texts and texts[-1].startswith("interrupted"), texts
    assert vi.interruption(_store(rrd)) == texts[-1]
    r = _inspect(rrd, "--failures")
    assert r.returncode in (0, 2), r.stderr
    ins = _clean_lines(r.stderr)
    assert len(ins) <= 2 and texts[-1] in ins[0], r.stderr
    return texts[-1]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
def test_ctrl_c_right_after_start_leaves_a_readable_recording_or_none(tmp_path):
    images = _write_set(tmp_path / "set", (120, 160))
    seen = []
    for k, delay in enumerate((0.0, 0.02, 0.1)):
        rrd = tmp_path / f"run{k}.rrd"
        p = _start(images, tmp_path, rrd)
        _wait_for_main(p)
        time.sleep(delay)
        rc, err = _interrupt(p)
        msg = _readable_or_none(rrd, err, rc)
        seen.append(msg)
        if msg is not None and msg.startswith("interrupted before the scans began"):
            assert msg.endswith(")"), msg  # says at which stage: "(while loading the images)"
        assert not (tmp_path / "out").exists()  # no empty output folder left behind
    assert any(m is not None for m in seen), seen


def test_ctrl_c_at_a_mid_point_says_which_stage(tmp_path):
    images = _write_set(tmp_path / "set", (240, 320))
    rrd = tmp_path / "run.rrd"
    p = _start(images, tmp_path, rrd)
    for line in p.stderr:  # non-tty progress: one line when a stage completes
        if line.startswith("features"):
            break
    rc, err = _interrupt(p)
    msg = _readable_or_none(rrd, err, rc)
    assert msg is not None  # the sink opened the file before the features
    stages = tuple(f"({w} {s})" for s in ("features", "geometry", "correspondence",
                                           "similarity") for w in ("during", "after"))
    assert msg.startswith("interrupted at scan") or msg.endswith(stages), msg


@pytest.mark.parametrize("where, stage, sig, code", [
    ("load_image_set", "while loading the images", KeyboardInterrupt, 130),
    ("choose_reference", "while choosing the reference", KeyboardInterrupt, 130),
    ("choose_reference", "while choosing the reference", "Terminated", 143)])
def test_interrupted_before_the_sink_exists(tmp_path, monkeypatch, capsys, where, stage,
                                            sig, code):
    """In process: a Ctrl-C / SIGTERM while loading or choosing the reference writes a
    recording that says so (with the names and size once the images are read)."""
    from dynremove import batch, commands, errors
    from dynremove.cli import main

    exc = errors.Terminated if sig == "Terminated" else sig
    images = _write_set(tmp_path / "set", (48, 64))
    target = commands.io if where == "load_image_set" else batch

    def cut(*a, **k):
        raise exc()

    monkeypatch.setattr(target, where, cut)
    rrd = tmp_path / "run.rrd"
    before = signal.getsignal(signal.SIGINT)
    rc = main(["run", str(images), "--out", str(tmp_path / "out"), "--record", str(rrd),
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == code and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()
    msg = f"interrupted before the scans began ({stage})"
    assert _log_texts(rrd)[-1] == msg
    store = _store(rrd)
    assert vi.interruption(store) == msg
    info = vi._static_values(store, "/run/info")
    if where == "choose_reference":  # the images were read: their names and size
        assert info["names"] == sorted(q.name for q in images.iterdir())
        assert info["height"] == [48] and info["width"] == [64]
    else:
        assert not info
    with pytest.raises(vi.InputError, match=r"before the scans began \(" + stage):
        vi.load_store(rrd)
    assert signal.getsignal(signal.SIGINT) is before  # restored


@pytest.mark.parametrize("after", [True, False])
def test_interrupted_while_writing_says_what_was_written(tmp_path, monkeypatch, capsys,
                                                         after):
    """A fresh-user trial's Ctrl-C during "writing" got "interrupted" alone, while all
    four outputs were written. After them: the note says they were all written;
    during them: that some files may be an earlier run's."""
    from dynremove import commands
    from dynremove.cli import main

    images = _write_set(tmp_path / "set", (48, 64))
    real = commands.write_outputs

    def cut(out, *a, **k):
        if after:
            real(out, *a, **k)
        else:
            (out / "clean.png").write_bytes(b"")  # (as if one file were in place)
        raise KeyboardInterrupt

    monkeypatch.setattr(commands, "write_outputs", cut)
    out = tmp_path / "out"
    rc = main(["run", str(images), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 130, err
    if after:
        assert "were all written before the interruption" in err, err
        assert (out / "report.json").is_file()
    else:
        assert "interrupted while writing" in err and "report.json" in err, err
    assert "nothing was written" not in err


def test_ctrl_c_inside_a_compiled_call_is_an_interruption(tmp_path, monkeypatch, capsys):
    """numba reports a Ctrl-C that lands inside a compiled call as a SystemError
    ("returned a result with an exception set") whose context is the
    KeyboardInterrupt: exit 130 with "interrupted", the recording ended as
    interrupted, not "internal error"."""
    from dynremove import commands
    from dynremove.cli import main

    def compiled_call(*a, **k):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function _assemble_sift>) returned a result "
                              "with an exception set")

    monkeypatch.setattr(commands, "remove_dynamic", compiled_call)
    images = _write_set(tmp_path / "set", (48, 64))
    rrd = tmp_path / "run.rrd"
    rc = main(["run", str(images), "--out", str(tmp_path / "out"), "--record", str(rrd),
               "--quiet"])
    err = capsys.readouterr().err
    assert rc == 130 and err.strip() == "dynremove: interrupted", err
    assert not (tmp_path / "out").exists()
    assert _log_texts(rrd)[-1] == "interrupted before the scans began (during features)"
    # anywhere else (no recording): the same exit, not an internal error
    rc = main(["run", str(images), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 130 and err.strip() == "dynremove: interrupted", err


def test_interruption_walks_the_cause_chain():
    from dynremove.errors import Terminated, interruption

    k = KeyboardInterrupt()
    assert interruption(k) is k
    try:
        try:
            raise Terminated()
        except Terminated:
            raise SystemError("wrapped")
    except SystemError as e:
        assert isinstance(interruption(e), Terminated)
    assert interruption(ValueError("plain")) is None
    loop = ValueError("a")
    loop.__context__ = ValueError("b")
    loop.__context__.__context__ = loop  # a cycle ends the walk
    assert interruption(loop) is None


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_a_ctrl_c_lost_in_a_finaliser_stops_the_run_at_the_next_stage(tmp_path, capsys):
    """Python drops an exception raised while a ``__del__`` runs ("Exception ignored
    in ...": llvmlite frees compiled objects so, and a Ctrl-C landed there in a
    trust test, whose run then ended with exit 0). The handler remembers the stop;
    the run raises it at its next stage: exit 130, no outputs."""
    from dynremove import commands
    from dynremove.cli import main

    class Finaliser:
        fired = False

        def __del__(self):
            if not Finaliser.fired:
                Finaliser.fired = True
                commands.request_stop(KeyboardInterrupt)  # as the SIGINT handler does

    real = commands.remove_dynamic

    def run_with_a_lost_ctrl_c(*a, **k):
        Finaliser()  # dropped at once: its KeyboardInterrupt is printed and ignored
        return real(*a, **k)

    images = _write_set(tmp_path / "set", (48, 64))
    out = tmp_path / "out"
    commands.remove_dynamic = run_with_a_lost_ctrl_c
    try:
        rc = main(["run", str(images), "--out", str(out), "--max-scans", "1"])
    finally:
        commands.remove_dynamic = real
    err = capsys.readouterr().err
    assert Finaliser.fired  # (pytest collects the ignored exception, not stderr)
    assert rc == 130 and "dynremove: interrupted" in err, err
    assert not (out / "clean.png").exists()
    commands.check_stop()  # nothing left pending for the next command


# a KeyboardInterrupt raised where the command first imports numba (or OpenCV):
# what a Ctrl-C in that second gives, at a deterministic point
_INTERRUPT_AT_IMPORT = """
import builtins, sys
real = builtins.__import__
def imp(name, *a, **k):
    if name == MODULE:
        raise KeyboardInterrupt
    return real(name, *a, **k)
builtins.__import__ = imp
from dynremove.entry import main
sys.exit(main())
"""


@pytest.mark.parametrize("module", ["numba", "cv2", None])
def test_a_ctrl_c_while_the_command_starts_is_one_line(tmp_path, module):
    """A Ctrl-C during the first second (the command still importing numba and
    OpenCV, before its own handler is set): exit 130 and one line, no Python
    traceback; a fresh-user trial saw one from numba's import at 0.5 s. With
    ``module``, the interrupt is raised where that module is first imported; with
    None, a real SIGINT is sent once the child has OpenCV or numba mapped (its
    import under way, or the run begun: both must end the same way)."""
    folder = _write_set(tmp_path / "set", (48, 64))
    code = (_INTERRUPT_AT_IMPORT.replace("MODULE", repr(module)) if module else
            "import sys; from dynremove.entry import main; sys.exit(main())")
    p = subprocess.Popen([sys.executable, "-c", code, "run", str(folder), "--out",
                          str(tmp_path / "out")], cwd=REPO, env=ENV,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=_sigint_default)
    if module is None:
        maps = Path(f"/proc/{p.pid}/maps")
        if not maps.exists():
            p.kill()
            pytest.skip("no /proc: cannot tell when the child is importing")
        t0 = time.monotonic()
        while p.poll() is None and time.monotonic() - t0 < 60:
            try:
                if re.search(r"cv2|numba", maps.read_text()):
                    break
            except OSError:
                break
            time.sleep(0.005)
        p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert "Traceback" not in err and "interrupted" in err, err
    assert not (tmp_path / "out" / "clean.png").exists()


def test_a_ctrl_c_after_the_run_finished_keeps_its_exit_status(tmp_path):
    """A Ctrl-C that arrives once the command has written its outputs (here: right
    after ``main`` returns, where the interpreter's exit joins the native threads)
    leaves exit 0: a fresh-user trial's late Ctrl-C turned a finished run, which had
    printed "wrote .../clean.png", into exit 130 with nothing said."""
    folder = _write_set(tmp_path / "set", (48, 64))
    code = ("import os, signal, sys, time; from dynremove.entry import main\n"
            "rc = main()\n"
            "os.kill(os.getpid(), signal.SIGINT); os.kill(os.getpid(), signal.SIGTERM)\n"
            "time.sleep(0.5)\n"
            "sys.exit(rc)")
    p = subprocess.run([sys.executable, "-c", code, "run", str(folder), "--out",
                        str(tmp_path / "out"), "-q"], cwd=REPO, env=ENV,
                       capture_output=True, text=True, timeout=300,
                       preexec_fn=_sigint_default)
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "interrupted" not in p.stderr, p.stderr
    assert (tmp_path / "out" / "clean.png").exists()


class _StopAtTheLastRows(RerunSink):
    """A sink whose recording of the scan's last rows is cut by a Ctrl-C."""

    def chunk(self, events, state):
        super().chunk(events, state)
        if max(events.rows) == self.H - 1:  # (scan 0 visits the rows top down)
            raise KeyboardInterrupt


@pytest.mark.parametrize("where", ["progress", "recording"])
def test_a_ctrl_c_as_the_scan_ends_keeps_its_maps(tmp_path, where):
    """A Ctrl-C that lands once the scan has visited its last row (as its end is told
    to the progress bar, or while its last rows are being recorded) keeps the whole
    scan's maps in the recording, and it says the run stopped after the scan; a
    fresh-user trial's Ctrl-C there lost them (session 65)."""
    from dynremove.pipeline import remove_dynamic

    scene = synth.make_scene(seed=0, n_views=4, size=(120, 160))
    full = remove_dynamic(scene.images, ref=scene.ref_index, params="default")
    path = tmp_path / f"{where}.rrd"
    cls = _StopAtTheLastRows if where == "recording" else RerunSink
    sink = cls(path, record_every_rows=8)

    def progress(stage, frac):
        if where == "progress" and stage == "scan 0" and frac >= 1.0:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        remove_dynamic(scene.images, ref=scene.ref_index, params="default", sink=sink,
                       progress=progress)
    sink.interrupted("during scan 0")
    maps = vi.read_scan_maps(path)
    assert [m["scan"] for m in maps] == [0]
    np.testing.assert_array_equal(np.isnan(maps[0]["M"]), np.isnan(full.M[0]))
    np.testing.assert_allclose(maps[0]["M"], full.M[0], atol=1e-4, equal_nan=True)
    # (the default preset's one scan: "after the scans")
    msg = vi.interruption(_store(path))
    assert msg.startswith("interrupted after") and "step" not in msg, msg
