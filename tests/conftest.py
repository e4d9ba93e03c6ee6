"""Shared fixtures: small synthetic scenes and the shared real data (if present)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    return Path(os.environ.get("DYNREMOVE_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def small_scene():
    from dynremove.evaluation import synth

    return synth.make_scene(seed=3, n_views=5, size=(72, 96), n_objects=1)


@pytest.fixture
def davis():
    d = data_dir() / "davis"
    if not d.is_dir():
        pytest.skip(f"real data not found at {d} (set DYNREMOVE_DATA to the shared data folder)")
    return d
