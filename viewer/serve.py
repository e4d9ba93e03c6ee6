"""Open a recording: the native viewer, or the web viewer served on loopback.

Both start the real ``rerun`` binary shipped in the ``rerun_cli`` package, not
the ``<venv>/bin/rerun`` Python wrapper (which runs the binary as a child, so
killing the wrapper's PID would leave the viewer running; RERUN_NOTES.md §7).
Every server is bound to 127.0.0.1 only (``rr.serve_web_viewer`` binds 0.0.0.0):
the web viewer's HTTP and gRPC ports, and the native viewer's gRPC port. Without a
display (Linux, neither ``DISPLAY`` nor ``WAYLAND_DISPLAY`` set) the native viewer
is not started: :func:`view` raises ``InputError`` that suggests ``--web``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import quote

from dynremove.errors import InputError

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


def has_display(env: dict[str, str] | None = None) -> bool:
    """Whether a native window can open (always True off Linux)."""
    env = os.environ if env is None else env
    if not sys.platform.startswith("linux"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def view_command(path: str | Path, *, web: bool = False, port: int = DEFAULT_GRPC_PORT,
                 web_port: int = DEFAULT_WEB_PORT, open_browser: bool = False) -> list[str]:
    """The command line :func:`view` runs. ``web``: rerun's ``--serve-web`` (it serves
    the page and prints nothing for us), or ``--web-viewer`` with ``open_browser``
    (the same, and it opens the system's browser)."""
    exe = rerun_binary()
    if web:
        return [exe, "--web-viewer" if open_browser else "--serve-web", "--bind",
                "127.0.0.1", "--port", str(port), "--web-viewer-port", str(web_port),
                str(path)]
    return [exe, "--bind", "127.0.0.1", "--port", str(port), str(path)]


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
    wait : block until the viewer exits; otherwise return the running process,
        which the caller must terminate. A Ctrl-C stops the viewer, then goes on
        up as the KeyboardInterrupt (the CLI's exit 130, as every command's).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording: {path}")
    if not web and not has_display(env):
        raise InputError(f"no display here (DISPLAY and WAYLAND_DISPLAY are unset): run "
                         f"`dynremove view {path} --web` and open the printed URL in a browser")
    # (on a machine without a display rerun's --web-viewer started a browser anyway,
    # left as a zombie: a trial; there the URL is all it prints)
    cmd = view_command(path, web=web, port=port, web_port=web_port,
                       open_browser=has_display(env))
    if web:  # rerun's own banner and URLs would confuse: print one URL, ours
        popen_kwargs.setdefault("stdout", subprocess.DEVNULL)
        popen_kwargs.setdefault("stderr", subprocess.DEVNULL)
    proc = subprocess.Popen(cmd, env=env, **popen_kwargs)
    if web:
        print(web_url(port=port, web_port=web_port), flush=True)
        print(f"serving {path} on 127.0.0.1 only; Ctrl-C stops it", file=sys.stderr)
    if not wait:
        return proc
    try:
        proc.wait()
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
