"""dynremove: detect moving objects in a multi-view image set and replace them
with the static background they hide (Kanojia & Raman, WACV).

Public API::

    from dynremove import remove_dynamic, Params, preset
    result = remove_dynamic(images, ref=3, params=preset("default"))
    result.clean, result.dynamic
"""

from dynremove.events import EventSink, MemorySink, NullSink
from dynremove.params import PRESETS, Params, preset
from dynremove.pipeline import Result, remove_dynamic

__all__ = ["remove_dynamic", "Result", "Params", "PRESETS", "preset",
           "EventSink", "NullSink", "MemorySink"]
__version__ = "0.1.0"
