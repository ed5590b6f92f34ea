"""The transport step of the constraint null-space basis (linearize.constrained).

Oracle: the definition ``N_{k+1} = Q_{k+1} polar(Q_{k+1}^T N_k)`` written with an explicit
orthonormal null basis ``Q`` (full SVD) and the polar factor from ``scipy.linalg.polar``
(independent code), against the closed form the module uses (projector and a small
eigenproblem, with its SVD fallback for large turns); and a wrong step (the projection
without the polar factor) must be told apart.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from linearize import constrained as c


def _definition(C: np.ndarray, N: np.ndarray) -> np.ndarray:
    _, s, vh = np.linalg.svd(C)
    Q = vh[int(np.sum(s > c.RANK_TOLERANCE * s[0])):].T
    U, _ = scipy.linalg.polar(Q.T @ N)
    return Q @ U


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(6, 20), st.integers(0, 2**31 - 1), st.sampled_from([None, -1.0]))
def test_projector_step_equals_the_definition(m, n, seed, limit):
    """Closed form (default limit) and the SVD fallback (limit -1 forces it) alike."""
    rng = np.random.default_rng(seed)
    C0 = rng.standard_normal((m, n))
    N = c._null(C0, n)  # orthonormal basis at the previous sample
    C1 = C0 + 0.1 * rng.standard_normal((m, n))  # the next sample's constraints
    saved = c.TRANSPORT_CLOSED_FORM_LIMIT
    try:
        if limit is not None:
            c.TRANSPORT_CLOSED_FORM_LIMIT = limit
        step = c._transport_step(c._row_space(C1), N)
    finally:
        c.TRANSPORT_CLOSED_FORM_LIMIT = saved
    ref = _definition(C1, N)
    # both are the orthonormal polar factor of the same n x r matrix P N: equal to round-off
    # (n eps, x 10) amplified by the polar factor's condition 1 / sigma_min(P N)
    sigma_min = float(np.linalg.svd(c._project(c._row_space(C1), N), compute_uv=False)[-1])
    assert sigma_min > 0
    assert np.max(np.abs(step - ref)) <= 10 * n * np.finfo(float).eps / sigma_min
    assert np.max(np.abs(C1 @ step)) <= 10 * n * np.finfo(float).eps * np.max(np.abs(C1))
    assert np.max(np.abs(step.T @ step - np.eye(N.shape[1]))) <= 10 * n * np.finfo(float).eps / sigma_min
    # a step without the polar factor (projection only) is not orthonormal: told apart
    wrong = c._project(c._row_space(C1), N)
    assert np.max(np.abs(wrong - ref)) > 1e-6
