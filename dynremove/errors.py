"""Errors that callers are meant to catch.

``InputError`` is the one error about the *user's* inputs (images, folders,
flags): the CLI maps it to exit code 2 with a one-line message. Every other
exception is an internal error (exit code 1).
"""

from __future__ import annotations


class InputError(ValueError):
    """The inputs cannot be processed (the CLI exits with code 2)."""


__all__ = ["InputError"]
