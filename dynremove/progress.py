"""A small progress bar on stderr (no dependency): one line per stage."""

from __future__ import annotations

import sys
import time
from typing import Mapping, TextIO


class ProgressBar:
    """Call with (stage, fraction); redraws at most every 0.1 s, newline per stage.

    ``labels`` renames stages on screen (e.g. the pipeline's "fusion" as the fill
    that runs); other stages are shown by their own name.
    """

    def __init__(self, *, enabled: bool = True, stream: TextIO | None = None, width: int = 28,
                 labels: Mapping[str, str] | None = None):
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.width = width
        self.labels = dict(labels or {})
        self.stage: str | None = None
        self.t_stage = time.perf_counter()
        self.t_draw = 0.0
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def label(self, stage: str) -> str:
        """The name ``stage`` is shown by."""
        return self.labels.get(stage, stage)

    def __call__(self, stage: str, frac: float) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if stage != self.stage:
            self.close()
            self.stage, self.t_stage = stage, now
        if frac < 1.0 and now - self.t_draw < 0.1:
            return
        self.t_draw = now
        if not self.tty and frac < 1.0:
            return  # logs get one line per stage
        n = int(round(self.width * min(max(frac, 0.0), 1.0)))
        bar = "#" * n + "-" * (self.width - n)
        line = f"{self.label(stage):<17} [{bar}] {100 * frac:5.1f} %  {now - self.t_stage:6.1f} s"
        self.stream.write(("\r" if self.tty else "") + line + ("" if self.tty else "\n"))
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.stage is not None and self.tty:
            self.stream.write("\n")
            self.stream.flush()
        self.stage = None
