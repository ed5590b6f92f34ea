"""Force Jacobians of the generic orbit's tangent blocks (linearize.periodic_orbit).

Oracles: one Richardson difference per column (independent of Exudyn's Jacobian code)
with its own error estimate from halving the step, and Exudyn's forces themselves (a
Jacobian that is wrong by a forward difference's error, or misses one coupling, must be
rejected; a reference too coarse to decide must not accept).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from linearize import periodic_orbit as po
from linearize.exudyn_system import ExudynSystem
from mbs_models.model_file import build_model, resolve_model

EPS = float(np.finfo(float).eps)


def _state(elements: int, amplitude: float = 1e-3, seed: int = 5):
    """The single link near its reference with generic rates (every coupling active)."""
    system = ExudynSystem(build_model(resolve_model("single-link", elements=elements), 2 * math.pi))
    rng = np.random.default_rng(seed)
    q = system.q_initial + amplitude * rng.standard_normal(system.n)
    v = rng.standard_normal(system.n)
    return system, q, v, 0.1


def _fd_bound(D_h: np.ndarray, D_h2: np.ndarray, J: np.ndarray, h: float) -> np.ndarray:
    """Entrywise error bound of the Richardson column differences ``D_h`` (step ``h``).

    Truncation: the rule is O(h^4), so err(h) ~ 16/15 |D(h) - D(h/2)|; a factor 2 for the
    asymptotic regime not being exact.  Round-off: the rule combines four differences with
    weights summing to 3/h, each of force terms of size <= |K| x 1 m (coordinates O(1)), so
    <= 3 eps |K| / h; a factor 10 instead of 3 for the terms' own assembly round-off.
    """
    return 2.0 * 16.0 / 15.0 * np.abs(D_h - D_h2) + 10.0 * EPS / h * float(np.max(np.abs(J)))


@pytest.mark.parametrize("elements", [2, 8])
def test_exudyn_jacobians_equal_column_differences_within_their_error(elements):
    system, q, v, t = _state(elements)
    K, C = system.force_jacobians(q, v, t)
    h = po.RICHARDSON_STEP
    K1, C1 = po._force_fd(system, q, v, np.zeros(system.n), t, h, True)
    K2, C2 = po._force_fd(system, q, v, np.zeros(system.n), t, h / 2, True)
    for J, D1, D2 in ((K, K1, K2), (C, C1, C2)):
        assert np.max(np.abs(J)) > 0
        assert np.all(np.abs(J - D1) <= _fd_bound(D1, D2, J, h))
    assert po._exudyn_jacobians_ok(system, q, v, np.zeros(system.n), t, h, True)


def test_check_accepts_the_exact_jacobian_where_the_base_step_is_too_coarse():
    """At 32 elements the Richardson difference along a random direction at the base step is off
    by more than the tolerance (the stiff beams' quartic term over a whole element; the old
    check rejected Exudyn's Jacobian for it and differenced all 135 columns); the refined
    reference accepts it.  State: coordinates perturbed by 1 cm (strains of a few per cent);
    the coarse mismatch depends on state and direction (measured 3e-10 ... 1.7e-7 over six
    seeds, 1.2e-8 on the 2 pi orbit); this seed is one where it is 17x the tolerance."""
    system, q, v, t = _state(32, amplitude=1e-2, seed=4)
    K, _ = system.force_jacobians(q, v, t)
    h = po.fd_steps(q, po.RICHARDSON_STEP)
    e = np.random.default_rng(11).standard_normal(system.n) * h / po.RICHARDSON_STEP
    scale = float(np.max(np.abs(K))) * float(np.max(np.abs(e)))
    coarse = po._richardson(lambda y: -system.rhs(y, v, t), q, e, po.RICHARDSON_STEP)
    assert float(np.max(np.abs(K @ e - coarse))) / scale > 10 * po.JACOBIAN_CHECK_TOLERANCE
    assert po._exudyn_jacobians_ok(system, q, v, np.zeros(system.n), t, po.RICHARDSON_STEP, True)


def _forward_difference_jacobian(system, q, v, t, step=1e-7):
    """``-df/dq`` by forward differences with Exudyn's default step (error ~ step |f''|)."""
    f0 = system.rhs(q, v, t)
    K = np.empty((system.n, system.n))
    for j in range(system.n):
        x = q.copy()
        x[j] += step
        K[:, j] = -(system.rhs(x, v, t) - f0) / step
    return K


@pytest.mark.parametrize("defect", ["forward difference", "missing coupling"])
def test_check_rejects_a_wrong_jacobian(monkeypatch, defect):
    system, q, v, t = _state(4)
    K, C = system.force_jacobians(q, v, t)
    if defect == "forward difference":
        wrong = _forward_difference_jacobian(system, q, v, t)
        assert np.max(np.abs(wrong - K)) > 10 * po.JACOBIAN_CHECK_TOLERANCE * np.max(np.abs(K))
    else:
        wrong = K.copy()
        i, j = np.unravel_index(np.argmax(np.abs(K - np.diag(np.diag(K)))), K.shape)  # largest coupling
        wrong[i, j] = 0.0
    monkeypatch.setattr(system, "force_jacobians", lambda *args: (wrong, C))
    assert not po._exudyn_jacobians_ok(system, q, v, np.zeros(system.n), t, po.RICHARDSON_STEP, True)


@pytest.mark.parametrize("row", ["hub", "softest"])
def test_check_rejects_a_small_defect_in_a_soft_row(monkeypatch, row):
    """A wrong entry far below the largest stiffness: 1e-3 N/m, the level that
    RICHARDSON_STEP's derivation calls significant, in a row whose true stiffness is zero
    (the hub's rows); and 1e-6 of the row in the softest nonzero row (100x the row-wise
    tolerance).  Both are below the former global threshold (1e-8 x max|K| = 3 N/m at 4
    elements, asserted), which accepted them; the row-wise check must not."""
    system, q, v, t = _state(4)
    K, C = system.force_jacobians(q, v, t)
    rows = np.max(np.abs(K), axis=1)
    if row == "hub":
        i = int(np.flatnonzero(rows == 0.0)[0])
        j = int(np.argmax(rows))
        defect = 1e-3
    else:
        i = int(np.argmin(np.where(rows > 0.0, rows, np.inf)))
        j = int(np.argmax(np.abs(K[i])))
        defect = 1e-6 * rows[i]
    assert defect < po.JACOBIAN_CHECK_TOLERANCE * np.max(np.abs(K)) / 10  # invisible to a global norm
    wrong = K.copy()
    wrong[i, j] += defect
    monkeypatch.setattr(system, "force_jacobians", lambda *args: (wrong, C))
    assert not po._exudyn_jacobians_ok(system, q, v, np.zeros(system.n), t, po.RICHARDSON_STEP, True)


def test_check_refuses_when_the_reference_cannot_be_made_accurate(monkeypatch):
    """No halvings allowed at 32 elements: the reference cannot reach its accuracy, so the
    check must not accept (differences everywhere, the safe side), rather than compare
    against a reference as wrong as the tolerance."""
    system, q, v, t = _state(32, amplitude=1e-2, seed=4)
    monkeypatch.setattr(po, "JACOBIAN_REFERENCE_HALVINGS", 0)
    assert not po._exudyn_jacobians_ok(system, q, v, np.zeros(system.n), t, po.RICHARDSON_STEP, True)


# --------------------------------------------------------------------------- coloured differences
def test_coloured_force_differences_equal_one_column_at_a_time():
    """Where Exudyn's Jacobians are not used, the force and damping columns are differenced in
    structurally orthogonal groups: the same rule, steps and function values per entry as one
    column at a time (a row sees one column per colour), so they agree to round-off only
    (bound: the round-off term of _fd_bound, no truncation term), with fewer evaluations."""
    system, q, v, t = _state(4)
    pattern = system.coupling_pattern()
    a = np.zeros(system.n)
    h = po.RICHARDSON_STEP
    KC = po._force_compressed(system, q, v, a, t, h, True, pattern, np.random.default_rng(0))
    assert KC is not None
    ref = po._force_fd(system, q, v, a, t, h, True)
    for J, R in zip(KC, ref):
        assert np.max(np.abs(R)) > 0
        assert np.max(np.abs(J - R)) <= 10.0 * EPS / h * float(np.max(np.abs(R)))
    assert len(pattern.force_colours) < system.n


def _pattern_without(pattern, i, j):
    """``pattern`` missing the force coupling ``(i, j)``, recoloured."""
    from linearize import collocation_solver as cs

    force = pattern.force.copy()
    force[i, j] = False
    return cs.CouplingPattern(force=force, reaction=pattern.reaction, force_colours=cs.colour_columns(force),
                              reaction_colours=pattern.reaction_colours)


def test_pattern_missing_one_weak_coupling_is_rejected():
    """A pattern missing one weak coupling: the weakest off-diagonal entry that is
    still >= 1e-4 of its own row (not the row's largest).  Its difference contributes
    ~|K_ij h_j| to row i, below a tenth of 1e-6 of the largest row's |K| |e| (the former
    global normalisation, asserted: it accepted this), but >= ~1e-4 of row i, 100 x the
    row-wise PATTERN_CHECK_TOLERANCE; the coloured differences must refuse, in
    tangent_blocks' route (_force_compressed) and in the structured collocation's
    (compressed_blocks)."""
    from linearize import collocation_solver as cs

    system, q, v, t = _state(4)
    pattern = system.coupling_pattern()
    K, _ = system.force_jacobians(q, v, t)
    rows = np.max(np.abs(K), axis=1, keepdims=True)
    off = pattern.force & ~np.eye(system.n, dtype=bool) & (np.abs(K) >= 1e-4 * rows) & (np.abs(K) < rows)
    weak = np.where(off, np.abs(K), np.inf)
    i, j = np.unravel_index(np.argmin(weak), K.shape)
    h = po.fd_steps(q, po.RICHARDSON_STEP)
    assert np.abs(K[i, j]) * 2 * h[j] < 0.1 * cs.PATTERN_CHECK_TOLERANCE * np.max(np.abs(K) @ h)
    wrong = _pattern_without(pattern, i, j)
    a = np.zeros(system.n)
    assert po._force_compressed(system, q, v, a, t, po.RICHARDSON_STEP, True, pattern,
                                np.random.default_rng(0)) is not None
    assert po._force_compressed(system, q, v, a, t, po.RICHARDSON_STEP, True, wrong,
                                np.random.default_rng(0)) is None
    args = (system, np.array([t]), q[None], v[None], a[None], np.zeros((1, system.m)))
    rule, steps = po._richardson, (lambda x: po.fd_steps(x, po.RICHARDSON_STEP))
    assert cs.compressed_blocks(*args, pattern, derivative=rule, steps=steps).pattern_mismatch \
        <= cs.PATTERN_CHECK_TOLERANCE
    with pytest.raises(cs.PatternError, match="outside the structural pattern"):
        cs.compressed_blocks(*args, wrong, derivative=rule, steps=steps)


def _merged_colouring(pattern):
    """A 'colouring' that puts every column into one group (coupled columns merged)."""
    from linearize import collocation_solver as cs

    return cs.CouplingPattern(force=pattern.force, reaction=pattern.reaction,
                              force_colours=(np.arange(pattern.size),), reaction_colours=pattern.reaction_colours)


def test_wrong_force_colouring_is_caught_and_falls_back(monkeypatch):
    """Merged coupled columns give a wrong Jacobian; the directional check rejects it and
    tangent_blocks differences one column at a time (equal to _force_fd); with the check
    switched off the wrong Jacobian comes through (what the check prevents)."""
    from linearize import collocation_solver as cs

    system, q, v, t = _state(4)
    wrong = _merged_colouring(system.coupling_pattern())
    a = np.zeros(system.n)
    h = po.RICHARDSON_STEP
    assert po._force_compressed(system, q, v, a, t, h, True, wrong, np.random.default_rng(0)) is None
    monkeypatch.setattr(system, "_coupling_pattern", wrong)
    times, Q, V, A = np.array([t]), q[None], v[None], a[None]
    L = np.zeros((1, system.m))
    tb = po.tangent_blocks(system, times, Q, V, A, L, use_exudyn_jacobian=False)
    K_ref, C_ref = po._force_fd(system, q, v, a, t, h, True)
    assert np.max(np.abs(tb.K_force[0] - K_ref)) <= 10.0 * EPS / h * float(np.max(np.abs(K_ref)))
    assert np.max(np.abs(tb.C[0] - C_ref)) <= 10.0 * EPS / h * float(np.max(np.abs(C_ref)))
    monkeypatch.setattr(cs, "PATTERN_CHECK_TOLERANCE", math.inf)
    unchecked = po.tangent_blocks(system, times, Q, V, A, L, use_exudyn_jacobian=False)
    assert np.max(np.abs(unchecked.K_force[0] - K_ref)) > 1e-3 * float(np.max(np.abs(K_ref)))
