"""Open a recording: the native viewer, or the web viewer served on loopback.

Both start the real ``rerun`` binary shipped in the ``rerun_cli`` package, not
the ``<venv>/bin/rerun`` Python wrapper (which runs the binary as a child, so
killing the wrapper's PID would leave the viewer running; RERUN_NOTES.md §7).
The web viewer is bound to 127.0.0.1 only (``rr.serve_web_viewer`` binds 0.0.0.0).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import quote

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090


def rerun_binary() -> str:
    """Path of the real rerun executable (next to the ``rerun_cli`` package)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).resolve().parent / "rerun"
        if exe.is_file() and os.access(exe, os.X_OK):
            return str(exe)
    except ImportError:
        pass
    found = shutil.which("rerun")
    if found is None:
        raise FileNotFoundError("rerun binary not found: pip install 'rerun-sdk==0.41.*'")
    return found


def web_url(*, port: int = DEFAULT_GRPC_PORT, web_port: int = DEFAULT_WEB_PORT) -> str:
    """URL of the web viewer page that loads the served recording."""
    return (f"http://127.0.0.1:{web_port}/?url="
            + quote(f"rerun+http://127.0.0.1:{port}/proxy", safe=""))


def view_command(path: str | Path, *, web: bool = False, port: int = DEFAULT_GRPC_PORT,
                 web_port: int = DEFAULT_WEB_PORT) -> list[str]:
    """The command line :func:`view` runs."""
    exe = rerun_binary()
    if web:
        return [exe, "--web-viewer", "--bind", "127.0.0.1", "--port", str(port),
                "--web-viewer-port", str(web_port), str(path)]
    return [exe, "--port", str(port), str(path)]


def view(path: str | Path, *, web: bool = False, port: int = DEFAULT_GRPC_PORT,
         web_port: int = DEFAULT_WEB_PORT, wait: bool = True,
         env: dict[str, str] | None = None, **popen_kwargs) -> subprocess.Popen:
    """Open ``path`` in the native viewer, or serve it to a browser (``web=True``).

    Parameters
    ----------
    path : the ``.rrd`` file (its embedded blueprint is used).
    web : serve the web viewer on ``http://127.0.0.1:<web_port>`` and print its URL.
    port : gRPC port of the viewer/server (native: if a viewer already listens
        there, the file is streamed into it).
    wait : block until the viewer exits (Ctrl-C stops it); otherwise return the
        running process, which the caller must terminate.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording: {path}")
    cmd = view_command(path, web=web, port=port, web_port=web_port)
    proc = subprocess.Popen(cmd, env=env, **popen_kwargs)
    if web:
        print(f"serving {path} on 127.0.0.1 only; open {web_url(port=port, web_port=web_port)}",
              file=sys.stderr)
    if not wait:
        return proc
    try:
        proc.wait()
    except KeyboardInterrupt:
        pass
    finally:
        stop(proc)
    return proc


def stop(proc: subprocess.Popen, timeout: float = 5.0) -> None:
    """Terminate a viewer started by :func:`view` (kill it if it does not exit)."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=timeout)
