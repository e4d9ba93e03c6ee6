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


def test_an_installed_copy_caches_the_kernels_outside_its_folder(tmp_path, monkeypatch):
    """numba's files beside an installed copy's source are not in pip's RECORD: a
    trial's ``pip uninstall`` left 109 of them (5.8 MB), and ``import dynremove``
    then still "worked" as an empty namespace package. An install in site-packages
    caches in the user's cache folder, a checkout beside its source."""
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    installed = tmp_path / "lib" / "python3.11" / "site-packages" / "dynremove"
    checkout = tmp_path / "src" / "dynremove"
    for pkg in (installed, checkout):
        (pkg / "method" / "scan").mkdir(parents=True)
    assert dynremove._numba_cache_dir(str(checkout)) is None
    assert dynremove._numba_cache_dir(str(installed)) == str(tmp_path / "cache" / "dynremove"
                                                             / "numba")


def test_a_cache_folder_another_user_could_write_is_not_used(tmp_path, monkeypatch):
    """numba loads its cache with pickle. The fallback folder in the shared temporary
    directory, made first by someone else or left writable by others, would run
    their code as this user (a trial planted one as root, mode 777, and the run
    loaded it): such a folder is skipped for a private temporary one."""
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    home = tmp_path / "home"
    monkeypatch.setenv("XDG_CACHE_HOME", str(home))
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    pkg = tmp_path / "lib" / "site-packages" / "dynremove"
    (pkg / "method" / "scan").mkdir(parents=True)
    planted = home / "dynremove" / "numba"
    planted.mkdir(parents=True)
    planted.chmod(0o777)  # writable by anyone
    shared = tmp_path / "tmp" / f"dynremove-numba-{os.getuid()}"
    shared.mkdir()
    shared.chmod(0o777)
    got = dynremove._numba_cache_dir(str(pkg))
    assert got not in (str(planted), str(shared))
    assert got.startswith(str(tmp_path / "tmp")) and os.stat(got).st_mode & 0o077 == 0
    planted.chmod(0o700)  # the user's own, private: used
    assert dynremove._numba_cache_dir(str(pkg)) == str(planted)
