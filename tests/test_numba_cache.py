"""The compiled kernels' cache where the install folder is read-only."""

from __future__ import annotations

import os

import dynremove


def test_a_read_only_install_caches_the_kernels_in_the_user_cache(tmp_path, monkeypatch):
    """numba caches beside the source; where that is not writable (a system-wide
    install) every command failed with "cannot cache function ...: no locator
    available" (a fresh-user trial, as another user than the installer). The cache
    then goes to $XDG_CACHE_HOME/dynremove/numba."""
    pkg = os.path.dirname(os.path.abspath(dynremove.__file__))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    real_access = os.access

    def read_only_install(path, mode, **kw):
        if os.path.abspath(path).startswith(pkg) and mode & os.W_OK:
            return False
        return real_access(path, mode, **kw)

    assert dynremove._numba_cache_dir(pkg) is None  # writable: numba's own choice
    monkeypatch.setattr(os, "access", read_only_install)
    got = dynremove._numba_cache_dir(pkg)
    assert got == str(tmp_path / "dynremove" / "numba") and os.path.isdir(got)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert dynremove._numba_cache_dir(pkg) is None  # the user's setting stands
