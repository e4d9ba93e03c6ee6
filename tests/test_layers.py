"""The layers, one way down (README: "Imports go one way down"), checked on every import.

    bottom (params, events, errors, io, video, validity, progress)
      <- method/ (the paper's Sec. 3)  <- refine/ (the default's engineered steps)
      <- pipeline  <- evaluation/  <- cli and the package's public API (__init__)

A module may import from its own layer or a lower one. Every ``import`` counts,
function-local ones included (a lazy import does not make a cycle go away).
``dynremove`` never imports ``rerun``, and imports ``viewer`` only from ``cli``
(and ``commands``, the CLI's sub-commands) and only lazily (inside a function).
``viewer`` may import anything of dynremove.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# (prefix, layer): the longest matching prefix wins
LAYERS: list[tuple[str, int]] = [
    ("dynremove.params", 0), ("dynremove.events", 0), ("dynremove.errors", 0),
    ("dynremove.io", 0), ("dynremove.progress", 0),
    ("dynremove.video", 0), ("dynremove.validity", 0),
    ("dynremove.method", 1),
    ("dynremove.refine", 2),
    ("dynremove.pipeline", 3),
    ("dynremove.evaluation", 4),
    ("dynremove.cli", 5), ("dynremove.commands", 5), ("dynremove.entry", 5),
    ("dynremove", 5),  # the package itself: the public API
]
# the command line (parser and sub-commands): the only modules that may import ``viewer``
VIEWER_IMPORTERS = {"dynremove.cli"}
LAYER_NAMES = {0: "bottom", 1: "method", 2: "refine", 3: "pipeline", 4: "evaluation",
               5: "cli/API"}


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def known_modules() -> set[str]:
    """Every module and package of dynremove/ and viewer/ (to resolve ``from X import y``)."""
    return {module_name(p) for pkg in ("dynremove", "viewer")
            for p in (ROOT / pkg).rglob("*.py")}


def layer_of(module: str) -> int | None:
    best = None
    for prefix, layer in LAYERS:
        if module == prefix or module.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    return None if best is None else best[1]


def imports_of(module: str, source: str, modules: set[str]) -> list[tuple[str, int, bool]]:
    """``(imported module, line, at top level)`` for every import statement of a source.

    ``from pkg import name`` counts as ``pkg.name`` when that is a module, else ``pkg``.
    Relative imports are resolved against ``module``.
    """
    tree = ast.parse(source)
    top = {id(n) for n in tree.body}
    # imports under a top-level ``if``/``try`` still run at import time
    for n in tree.body:
        if isinstance(n, (ast.If, ast.Try)):
            top |= {id(m) for m in ast.walk(n)}
    is_pkg = (ROOT / Path(*module.split(".")) / "__init__.py").is_file()
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            out += [(a.name, n.lineno, id(n) in top) for a in n.names]
        elif isinstance(n, ast.ImportFrom):
            base = n.module or ""
            if n.level:
                pkg = module.split(".") if is_pkg else module.split(".")[:-1]
                pkg = pkg[: len(pkg) - (n.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            for a in n.names:
                full = f"{base}.{a.name}"
                out.append((full if full in modules else base, n.lineno, id(n) in top))
    return out


def violations(module: str, source: str, modules: set[str] | None = None) -> list[str]:
    """Every import of ``module`` (given its source) that breaks the layering."""
    modules = known_modules() if modules is None else modules
    me = layer_of(module)
    bad = []
    for target, line, at_top in imports_of(module, source, modules):
        root = target.split(".")[0]
        where = f"{module}:{line} imports {target}"
        if module.startswith("dynremove"):
            if root == "rerun":
                bad.append(f"{where}: dynremove never imports rerun")
            elif root == "viewer":
                if module not in VIEWER_IMPORTERS:
                    bad.append(f"{where}: only dynremove.cli may import the viewer")
                elif at_top:
                    bad.append(f"{where}: the CLI imports the viewer lazily (in a function)")
            elif root == "dynremove":
                them = layer_of(target)
                if me is not None and them is not None and them > me:
                    bad.append(f"{where}: upward import ({LAYER_NAMES[me]} -> "
                               f"{LAYER_NAMES[them]})")
    return bad


def _sources() -> list[Path]:
    return sorted((ROOT / "dynremove").rglob("*.py")) + sorted((ROOT / "viewer").rglob("*.py"))


def test_no_upward_imports():
    modules = known_modules()
    bad = []
    for path in _sources():
        bad += violations(module_name(path), path.read_text(encoding="utf-8"), modules)
    assert not bad, "layering broken:\n" + "\n".join(bad)


def test_every_dynremove_module_has_a_layer():
    assert all(layer_of(module_name(p)) is not None for p in (ROOT / "dynremove").rglob("*.py"))


@pytest.mark.parametrize("module, source", [
    # method imports refine (inside a function: still counted)
    ("dynremove.method.features", "def f():\n    from dynremove.refine import fill\n"),
    ("dynremove.method.scan.driver", "from dynremove.refine.mask import refine_mask\n"),
    # a bottom module imports the pipeline, by ``import`` and by ``from ... import``
    ("dynremove.params", "import dynremove.pipeline\n"),
    ("dynremove.io", "from dynremove import pipeline\n"),
    ("dynremove.errors", "from dynremove import remove_dynamic\n"),  # the package API
    # the pipeline imports evaluation; evaluation imports the CLI
    ("dynremove.pipeline", "from dynremove.evaluation.metrics import jaccard\n"),
    ("dynremove.evaluation.bench", "def g():\n    from dynremove.cli import params_from_args\n"),
    # a relative import upwards
    ("dynremove.refine.fill", "from ..pipeline import prepare\n"),
    # the viewer and rerun
    ("dynremove.pipeline", "def h():\n    import viewer.sink\n"),
    ("dynremove.cli", "from viewer.sink import RerunSink\n"),
    ("dynremove.commands", "from viewer.sink import RerunSink\n"),
    ("dynremove.commands", "def cmd():\n    from viewer.serve import view\n"),
    ("dynremove.video", "from dynremove.pipeline import prepare\n"),
    ("dynremove.events", "import rerun as rr\n"),
])
def test_checker_finds_planted_violations(module, source):
    assert violations(module, source), f"missed a planted violation in {module}"


@pytest.mark.parametrize("module, source", [
    ("dynremove.refine.fill", "from dynremove.method.correspondence import dense_correspondence\n"),
    ("dynremove.refine.mask", "from dynremove.refine.fields import source_votes\n"),
    ("dynremove.evaluation.composite", "from dynremove.evaluation import baselines\n"),
    ("dynremove.cli", "def cmd():\n    from viewer.serve import view\n"),
    ("dynremove.io", "from dynremove.video import read_video\n"),
    ("dynremove.method.geometry", "import cv2\nimport numpy as np\n"),
    ("viewer.sink", "from dynremove.events import EventBatch\nimport rerun\n"),
])
def test_checker_accepts_allowed_imports(module, source):
    assert not violations(module, source)
