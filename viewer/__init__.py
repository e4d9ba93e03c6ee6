"""Rerun side of dynremove: the recording sink, its layout and read-back tools.

The only package (with the CLI) that imports ``rerun``. Dependencies point one
way: ``viewer -> dynremove``.
"""

from viewer.blueprint import make_blueprint, make_compare_blueprint
from viewer.sink import RerunSink

__all__ = ["RerunSink", "make_blueprint", "make_compare_blueprint"]
