"""Where the compiled kernels spend their time: the scan under Linux ``perf``.

``perf`` samples numba's compiled code but cannot name it: the code lives in
memory that no file describes. This script writes ``/tmp/perf-<pid>.map`` (the
map format ``perf`` reads for JIT code: start, size and name per line) for every
function that numba compiled in the process, then runs the scan of the bench
scene (7 synthetic views of 854×480, as ``dynremove bench``) a few times::

    perf record -F 4000 -o /tmp/perf.data python examples/perf_kernels.py --threads 2
    perf report -i /tmp/perf.data --no-children --sort symbol

The compilation's samples (the interpreter, LLVM) are in the profile too: read
the compiled functions' shares among themselves, or raise ``--runs``.
Session 76 found this way that numba's reference counting (``NRT_incref``,
``NRT_decref``) took a quarter of the scan's decisions (README, Speed). Functions
that numba inlines (``inline="always"``) have no symbol of their own: their time
is their caller's. A function loaded from numba's on-disk cache has no module to
read names from, so the script compiles into a fresh cache folder of its own,
removed at exit (about 20 s; with ``NUMBA_CACHE_DIR`` set, that folder is used and
what it already holds is not mapped). It reads numba's internals
(``_final_module``, the code generator's engine), which may change between numba
versions.
"""

from __future__ import annotations

import argparse
import atexit
import os
import sys
import tempfile
from types import ModuleType


def write_perf_map(modules: list[ModuleType], path: str | None = None) -> int:
    """Write a ``perf`` map of the numba functions compiled so far in this process.

    Parameters
    ----------
    modules : list of modules
        Their numba dispatchers (module attributes with ``overloads``), and the
        libraries those link (a ``parallel=True`` function's loop body), are
        mapped.
    path : str, optional
        Default ``/tmp/perf-<pid>.map``, where ``perf report`` looks.

    Returns
    -------
    int
        The number of functions mapped. A function's size is the distance to the
        next mapped address (the code generator does not give it), at most 1 MiB.
    """
    libraries, seen = [], set()

    def walk(lib):
        if id(lib) in seen:
            return
        seen.add(id(lib))
        libraries.append(lib)
        for linked in getattr(lib, "_linking_libraries", ()):
            walk(linked)

    for mod in modules:
        for obj in vars(mod).values():
            for cres in getattr(obj, "overloads", {}).values():
                walk(cres.library)
    entries = set()
    for lib in libraries:
        module = getattr(lib, "_final_module", None)
        if module is None:  # loaded from the on-disk cache: no names to read
            continue
        for fn in module.functions:
            if fn.is_declaration:
                continue
            address = lib._codegen._engine.get_function_address(fn.name)
            if address:
                entries.add((address, fn.name))
    ordered = sorted(entries)
    with open(path or f"/tmp/perf-{os.getpid()}.map", "w") as fh:
        for i, (address, name) in enumerate(ordered):
            size = ordered[i + 1][0] - address if i + 1 < len(ordered) else 4096
            fh.write(f"{address:x} {min(size, 1 << 20):x} {name}\n")
    return len(ordered)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--threads", type=int, default=2, help="numba threads (default 2)")
    ap.add_argument("--runs", type=int, default=6, help="timed scans (default 6)")
    ap.add_argument("--preset", choices=("default", "paper"), default="default")
    args = ap.parse_args(argv)
    # before numba is imported: a fresh cache, so that every kernel is compiled here
    # (removed at exit)
    if "NUMBA_CACHE_DIR" not in os.environ:
        cache = tempfile.TemporaryDirectory(prefix="perf-kernels-")
        atexit.register(cache.cleanup)
        os.environ["NUMBA_CACHE_DIR"] = cache.name
    import numba

    from dynremove import preset
    from dynremove.evaluation import synth
    from dynremove.events import NullSink
    from dynremove.method.scan import _kernels, driver
    from dynremove.pipeline import prepare

    params = preset(args.preset)
    scene = synth.make_scene(seed=0, n_views=7, size=(480, 854))
    inputs, _ = prepare(scene.images, scene.ref_index, params)
    numba.set_num_threads(args.threads)
    driver.run_scans(inputs.copy(), params, sink=NullSink())  # compiles
    n = write_perf_map([_kernels, driver])
    print(f"perf map: {n} functions (/tmp/perf-{os.getpid()}.map)", file=sys.stderr)
    times = []
    for _ in range(args.runs):
        _, _, summaries = driver.run_scans(inputs.copy(), params, sink=NullSink())
        times.append(sum(float(s["seconds"]) for s in summaries))
    px = scene.images[0].shape[0] * scene.images[0].shape[1]
    print(f"{args.runs} runs of the scans ({args.preset}, {args.threads} threads): fastest "
          f"{min(times):.3f} s, median {sorted(times)[len(times) // 2]:.3f} s "
          f"({px / min(times) / 1e6:.2f} Mpx/s a run)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
