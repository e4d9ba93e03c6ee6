"""dynremove: detect moving objects in a multi-view image set and replace them
with the static background they hide (Kanojia & Raman, WACV).

Public API::

    from dynremove import remove_dynamic, Params, preset
    result = remove_dynamic(images, ref=3, params=preset("default"))
    result.clean, result.dynamic

``Params()`` and ``remove_dynamic``'s default are the ``default`` preset; the
method as written in the paper is ``preset("paper")`` (``PAPER``).

Layout (imports go one way down, ``tests/test_layers.py``): ``params``,
``events``, ``errors``, ``io`` (with ``video``, ``validity``), ``progress`` ←
``method/`` (the paper, Sec. 3) ← ``refine/`` (the default's engineered steps)
← ``pipeline`` ← ``evaluation/`` ← ``cli`` (with ``commands``).
"""

from dynremove.errors import InputError
from dynremove.events import EventSink, MemorySink, NullSink
from dynremove.params import DEFAULT, PAPER, PRESETS, Params, preset
from dynremove.pipeline import Result, remove_dynamic

__all__ = ["remove_dynamic", "Result", "Params", "PRESETS", "DEFAULT", "PAPER", "preset",
           "InputError", "EventSink", "NullSink", "MemorySink"]
__version__ = "0.1.0"
