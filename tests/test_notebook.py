"""examples/teaching_demo.ipynb runs headless (nbclient) and prints the probe's verdict.

Needs the ``notebook`` extra (``pip install -e ".[notebook]"``); skipped without it.
The kernel is this interpreter (a kernel spec in a temporary directory points at
``sys.executable``), so no Jupyter kernel has to be installed globally.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

NEEDS = "needs the notebook extra: pip install -e '.[notebook]'"
nbclient = pytest.importorskip("nbclient", reason=NEEDS)
pytest.importorskip("rerun_notebook", reason=NEEDS)
pytest.importorskip("ipykernel", reason=NEEDS)
nbformat = pytest.importorskip("nbformat", reason=NEEDS)

from jupyter_client.kernelspec import KernelSpecManager  # noqa: E402  (after the skips)
from jupyter_client.manager import KernelManager  # noqa: E402

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "teaching_demo.ipynb"
KERNEL = "dynremove-test"


def _kernel_manager(tmp: Path) -> KernelManager:
    """A kernel manager whose only kernel runs ``sys.executable -m ipykernel_launcher``."""
    spec_dir = tmp / "kernels" / KERNEL
    spec_dir.mkdir(parents=True)
    (spec_dir / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "dynremove (test)", "language": "python"}))
    ksm = KernelSpecManager(kernel_dirs=[str(tmp / "kernels")], ensure_native_kernel=False)
    return KernelManager(kernel_name=KERNEL, kernel_spec_manager=ksm)


def test_teaching_notebook_runs(tmp_path, monkeypatch):
    out = tmp_path / "teaching.rrd"
    monkeypatch.setenv("DYNREMOVE_NOTEBOOK_OUT", str(out))  # the kernel inherits the environment
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), \
        "commit the notebook with its outputs cleared"
    assert "widgets" not in nb.metadata, "commit the notebook without widget state"

    client = nbclient.NotebookClient(nb, km=_kernel_manager(tmp_path), timeout=120,
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()  # raises CellExecutionError on the first failing cell

    assert out.exists() and out.stat().st_size > 0
    text = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code"
                   for o in c.get("outputs", []) if o.get("output_type") == "stream")
    assert "4 scans" in text
    assert "pixel (80, 60): removed (in the final mask)" in text
    assert "the scans: dynamic in scan 0" in text
    assert "M =" in text and "final L = dynamic, ground truth = dynamic" in text
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
