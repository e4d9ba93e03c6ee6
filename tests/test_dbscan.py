"""The compiled DBSCAN equals scikit-learn's on random point sets."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from dynremove.method.scan._kernels import _dbscan


@pytest.mark.parametrize("min_pts", [1, 2, 3, 4])
def test_dbscan_matches_sklearn(min_pts):
    rng = np.random.default_rng(min_pts)
    for trial in range(300):
        n = int(rng.integers(1, 15))
        X = rng.normal(size=(n, 2)) * rng.uniform(0.2, 2.0)
        if trial % 3 == 0:  # clumps with border points
            X[: n // 2] *= 0.1
        D = np.sqrt(((X[:, None] - X[None]) ** 2).sum(-1))
        eps = float(rng.uniform(0.1, 1.5))
        want = DBSCAN(eps=eps, min_samples=min_pts, metric="precomputed").fit(D).labels_
        labels = np.empty(n, np.int64)
        k = _dbscan(D, n, eps, min_pts, labels, np.empty(n, np.bool_),
                    np.empty(n * n + 1, np.int64))
        np.testing.assert_array_equal(labels, want)
        assert k == (want.max() + 1 if n else 0)


def test_dbscan_ties_at_eps_count_as_neighbours():
    D = np.array([[0.0, 0.5], [0.5, 0.0]])
    labels = np.empty(2, np.int64)
    _dbscan(D, 2, 0.5, 2, labels, np.empty(2, np.bool_), np.empty(5, np.int64))
    assert labels.tolist() == [0, 0]
