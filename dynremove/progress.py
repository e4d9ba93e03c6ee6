"""A small progress bar on stderr (no dependency): one line per stage."""

from __future__ import annotations

import sys
import time
from typing import Mapping, TextIO

from dynremove.params import Params


def stage_labels(params: Params) -> dict[str, str]:
    """The names the progress bar and ``bench`` give the pipeline's stages, by what
    runs.

    The pipeline reports both fills as "fusion" (report.json keeps that key in
    ``seconds``); the bar names the fill the parameters choose.
    """
    return {"fusion": "fill by selection" if params.fill == "select" else "fused fill"}


class ProgressBar:
    """Call with (stage, fraction); redraws at most every 0.1 s, newline per stage.

    ``labels`` renames stages on screen (e.g. the pipeline's "fusion" as the fill
    that runs); other stages are shown by their own name.

    A stage's clock starts at its ``(stage, 0.0)`` call; a stage whose first call
    comes later (the scans, after their first rows) starts where the stage before
    it reached 100 %. The pipeline's stages follow one another, so their lines
    add up to its run and equal its ``timings`` (report.json's ``seconds``); work
    between two stages that are not consecutive (a recording's logging) is in no
    line. Not on a terminal, a stage gets one line, when it
    first reaches 100 %.
    """

    def __init__(self, *, enabled: bool = True, stream: TextIO | None = None, width: int = 28,
                 labels: Mapping[str, str] | None = None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.width = width
        self.labels = dict(labels or {})
        self.stage: str | None = None
        self.t_stage = time.perf_counter()
        self.t_done: float | None = None  # when the current stage reached 100 %
        self.t_draw = 0.0
        self.open = False  # a terminal line is drawn and not ended yet
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def label(self, stage: str) -> str:
        """The name ``stage`` is shown by."""
        return self.labels.get(stage, stage)

    def __call__(self, stage: str, frac: float) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if stage != self.stage:
            # a stage starts at its (stage, 0.0) call; one whose first call comes later
            # (the scans: after their first rows) where the stage before it ended.
            # (Work between a stage's end and the next one's start, as a recording's,
            # is in no line, as in report.json's seconds: a trial saw "coverage 0.4 s"
            # printed against 0.04 s in report.json with --record)
            start = now if frac <= 0.0 or self.t_done is None else self.t_done
            self._end_line()
            self.stage, self.t_stage, self.t_done, self.t_draw = stage, start, None, 0.0
        if frac >= 1.0:
            if self.t_done is not None and not self.tty:
                return  # its line is written
            self.t_done = now
        elif now - self.t_draw < 0.1:
            return
        self.t_draw = now
        if not self.tty and frac < 1.0:
            return  # logs get one line per stage
        n = int(round(self.width * min(max(frac, 0.0), 1.0)))
        bar = "#" * n + "-" * (self.width - n)
        line = f"{self.label(stage):<17} [{bar}] {100 * frac:5.1f} %  {now - self.t_stage:6.1f} s"
        self.stream.write(("\r" if self.tty else "") + line + ("" if self.tty else "\n"))
        self.stream.flush()
        self.open = self.tty

    def note(self, text: str) -> None:
        """Write ``text`` as a line of its own now, between the stages' lines (a
        note as soon as it is known): on a terminal, the bar being drawn is ended
        first and goes on below."""
        self._end_line()
        self.stream.write(text + "\n")
        self.stream.flush()

    def _end_line(self) -> None:
        if self.open:
            self.stream.write("\n")
            self.stream.flush()
            self.open = False

    def close(self, *, failed: bool = False) -> None:
        """End the bar. ``failed`` (the command stops on an error): on a terminal, the
        line of a stage that has not reached 100 % is erased, not ended, so that the
        error is the last word (a trial saw "load [----] 0.0 %" above every input
        error)."""
        if self.enabled:
            if failed and self.open and self.tty and self.t_done is None:
                self.stream.write("\r\033[K")
                self.stream.flush()
                self.open = False
            self._end_line()
        self.stage, self.t_done = None, None


class SetProgress:
    """The set a batch is running, on one line: ``"[k/n] NAME: stage NN % (T s)"``.

    On a terminal the line is redrawn at most every 0.1 s and erased by
    ``clear`` (before the set's own line, when it finishes); elsewhere (a log)
    one line says that the set is running, at its pipeline's first step (a set
    skipped as done before gets none). A batch ran for minutes with nothing on
    the screen between two sets' lines (a fresh-user trial).
    """

    def __init__(self, prefix: str, *, stream: TextIO | None = None,
                 labels: Mapping[str, str] | None = None):
        self.prefix = prefix
        self.stream = stream or sys.stderr
        self.labels = dict(labels or {})
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0, self.t_draw = time.perf_counter(), 0.0
        self.drawn = False
        self.said = False  # (not on a terminal) its one line is written

    def __call__(self, stage: str, frac: float) -> None:
        if not self.tty:
            if not self.said:
                self.stream.write(f"{self.prefix} running\n")
                self.stream.flush()
                self.said = True
            return
        now = time.perf_counter()
        if now - self.t_draw < 0.1 and frac < 1.0:
            return
        self.t_draw = now
        self.stream.write(f"\r\033[K{self.prefix} {self.labels.get(stage, stage)} "
                          f"{100 * min(max(frac, 0.0), 1.0):3.0f} %  ({now - self.t0:.0f} s)")
        self.stream.flush()
        self.drawn = True

    def clear(self) -> None:
        """Erase the line (on a terminal), so that the next line takes its place."""
        if self.drawn:
            self.stream.write("\r\033[K")
            self.stream.flush()
            self.drawn = False
