"""The ``dynremove`` command's entry point: imports the command line, then runs it.

Importing it (numba, OpenCV, the kernels' caches) takes about a second; a Ctrl-C
in that second ends the command with its one line and exit status 130, as one
during the run does (``cli.main``), not with a Python traceback.
"""

from __future__ import annotations

import sys


def main() -> int:
    try:
        from dynremove.cli import main as run

        return run()  # (which handles a Ctrl-C from the moment its handler is set)
    except KeyboardInterrupt:
        print("dynremove: interrupted (nothing was written)", file=sys.stderr)
        return 130


__all__ = ["main"]
