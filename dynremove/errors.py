"""Errors that callers are meant to catch.

``InputError`` is the one error about the *user's* inputs (images, folders,
flags): the CLI maps it to exit code 2 with a one-line message. Every other
exception is an internal error (exit code 1).
"""

from __future__ import annotations


class InputError(ValueError):
    """The inputs cannot be processed (the CLI exits with code 2)."""


class Note(UserWarning):
    """A run's note (``Result.warnings``): what it did that the user should know (a
    photo left out, pixels inpainted, a mover that lingered). Issued as a warning of
    this category, so a caller can filter them: ``warnings.simplefilter("ignore",
    dynremove.Note)`` (the notes stay in ``Result.warnings``)."""


class Terminated(BaseException):
    """SIGTERM, raised in the main thread between chunks of work."""


def interruption(e: BaseException | None) -> BaseException | None:
    """The KeyboardInterrupt or Terminated behind ``e``: ``e`` itself, or one in its
    ``__cause__`` / ``__context__`` chain; None if there is none.

    A Ctrl-C that lands inside a compiled (numba) call can surface as a
    ``SystemError`` ("returned a result with an exception set") whose context is
    the KeyboardInterrupt: that is still an interruption, not an internal error.
    """
    seen: set[int] = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, (KeyboardInterrupt, Terminated)):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


__all__ = ["InputError", "Note", "Terminated", "interruption"]
