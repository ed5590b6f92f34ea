"""The linear assignment solver of the Floquet engine against scipy.optimize.linear_sum_assignment."""
import math

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from stability.assignment import linear_assignment


def _total(C, cols):
    return float(C[np.arange(C.shape[0]), cols].sum())


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 17, 40, 68])
def test_optimal_cost_equals_scipy(n):
    rng = np.random.default_rng(n)
    for trial in range(12):
        # continuous costs, integer costs (many ties), and a near-identity pairing with conflicts
        if trial % 3 == 0:
            C = rng.random((n, n))
        elif trial % 3 == 1:
            C = rng.integers(0, 4, (n, n)).astype(float)
        else:
            C = np.abs(rng.normal(size=(n, n)))
            C[np.arange(n), np.arange(n)] = 1e-3
            C[:, 0] = 1e-4  # every row's cheapest column is the first
        cols = linear_assignment(C)
        assert sorted(cols.tolist()) == list(range(n))
        r, c = linear_sum_assignment(C)
        assert _total(C, cols) == pytest.approx(_total(C, c[np.argsort(r)]), rel=1e-12, abs=1e-12)


def test_greedy_nearest_is_not_taken_when_it_is_not_optimal():
    # both rows are cheapest on column 0: the greedy pairing costs 11, the optimum 3
    C = np.array([[1.0, 2.0], [1.0, 10.0]])
    assert linear_assignment(C).tolist() == [1, 0]


def test_empty_and_bad_input():
    assert linear_assignment(np.zeros((0, 0))).size == 0
    with pytest.raises(ValueError, match="square"):
        linear_assignment(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        linear_assignment(np.array([[0.0, np.nan], [1.0, 0.0]]))


@pytest.mark.parametrize("n", [2, 3, 4, 6, 8, 12])
def test_small_lists_equal_scipy(n):
    """The list path of small systems (the Floquet engine's small-system pairing) is optimal too."""
    rng = np.random.default_rng(100 + n)
    for trial in range(30):
        C = rng.random((n, n)) if trial % 2 else rng.integers(0, 3, (n, n)).astype(float)
        cols = linear_assignment(C.tolist())
        assert sorted(cols.tolist()) == list(range(n))
        r, c = linear_sum_assignment(C)
        assert _total(C, cols) == pytest.approx(_total(C, c[np.argsort(r)]), rel=1e-12, abs=1e-12)
    assert linear_assignment([[1.0, 2.0], [1.0, 10.0]]).tolist() == [1, 0]
    with pytest.raises(ValueError, match="non-finite"):
        linear_assignment([[0.0, math.inf], [1.0, 0.0]])
