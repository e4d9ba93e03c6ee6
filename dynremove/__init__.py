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

import os

# numba's OpenMP threads wait for work asleep, not spinning: the scan starts a
# parallel loop a few dozen times a pass, and with another process on the cores a
# spinning thread holds the core that the thread it waits for needs (a pass of
# 1.3 s took 6-16 s on a busy 2-core machine when it met at a barrier a few thousand
# times a pass). Read when numba first starts its threads; a value the user set wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _private_dir(d: str) -> bool:
    """Whether folder ``d`` exists (created 0700 if not) as a real folder of this user
    that no one else can write to. numba loads its cache files with pickle: a folder
    in the shared temporary directory that another user made first (or a link) would
    let them run code as this user (a fresh-user trial)."""
    import stat

    try:
        os.makedirs(d, mode=0o700, exist_ok=True)
        st = os.lstat(d)
    except OSError:
        return False
    if not stat.S_ISDIR(st.st_mode) or not os.access(d, os.W_OK):
        return False
    if hasattr(os, "getuid") and (st.st_uid != os.getuid() or st.st_mode & 0o022):
        return False
    return True


def _installed(package_dir: str) -> bool:
    """Whether the package runs from an installed copy (site-packages), not a checkout."""
    parts = os.path.normpath(package_dir).split(os.sep)
    return "site-packages" in parts or "dist-packages" in parts


def _numba_cache_dir(package_dir: str) -> str | None:
    """Where numba should cache the compiled kernels when not beside the source.

    numba caches in the ``__pycache__`` folders next to the code. An installed copy
    keeps its folders clean (``pip uninstall`` does not know numba's files: a trial
    found 109 of them left, 5.8 MB, and ``import dynremove`` still "working"), and a
    user who cannot write there (a system-wide install, a shared checkout) got a
    traceback from any command. Then the cache goes to
    ``$XDG_CACHE_HOME/dynremove/numba`` (``~/.cache`` by default), else to a per-user
    folder in the temporary directory, each only where it is this user's own and
    private (``_private_dir``), else to a new private temporary folder (compiled
    anew each run). None where a checkout's source folder is writable (numba's own
    choice stands) or ``NUMBA_CACHE_DIR`` is set.
    """
    if os.environ.get("NUMBA_CACHE_DIR"):
        return None
    kernels = os.path.join(package_dir, "method", "scan")
    pycache = os.path.join(kernels, "__pycache__")
    if not _installed(package_dir) and os.access(pycache if os.path.isdir(pycache)
                                                 else kernels, os.W_OK):
        return None
    import tempfile

    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid() if hasattr(os, "getuid") else os.getpid()
    for d in (os.path.join(home, "dynremove", "numba"),
              os.path.join(tempfile.gettempdir(), f"dynremove-numba-{uid}")):
        if _private_dir(d):
            return d
    try:
        return tempfile.mkdtemp(prefix="dynremove-numba-")
    except OSError:
        return None


_cache = _numba_cache_dir(os.path.dirname(os.path.abspath(__file__)))
if _cache is not None:  # read when numba is first imported
    os.environ["NUMBA_CACHE_DIR"] = _cache

# the public API, imported when first used: ``import dynremove`` (and the command's
# entry, ``dynremove.entry``) stays light, so that a Ctrl-C in the first second of
# a run meets the entry's handler, not an import of numba and OpenCV
_API = {"remove_dynamic": "dynremove.pipeline", "Result": "dynremove.pipeline",
        "Params": "dynremove.params", "PRESETS": "dynremove.params",
        "DEFAULT": "dynremove.params", "PAPER": "dynremove.params",
        "preset": "dynremove.params", "InputError": "dynremove.errors",
        "Note": "dynremove.errors",
        "EventSink": "dynremove.events", "NullSink": "dynremove.events",
        "MemorySink": "dynremove.events"}


def __getattr__(name: str):
    if name in _API:
        import importlib

        value = getattr(importlib.import_module(_API[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'dynremove' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


__all__ = ["remove_dynamic", "Result", "Params", "PRESETS", "DEFAULT", "PAPER", "preset",
           "InputError", "Note", "EventSink", "NullSink", "MemorySink"]
__version__ = "0.1.0"
