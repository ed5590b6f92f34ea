"""Structured collocation Newton (linearize.collocation_solver) against the dense route.

Oracles: the dense route's own residual and Newton matrix (independent code:
one central difference per column, a dense 4-D assembly), the definition of a
structurally orthogonal colouring, and Exudyn's forces themselves (a pattern
that misses a coupling must be rejected, a wrong Newton matrix must not
converge).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from linearize import collocation_solver as cs
from linearize import periodic_orbit as po
from linearize.periodic_orbit import OrbitConvergenceError, find_orbit
from mbs_models.model_file import build_model, resolve_model

HERE = Path(__file__).parent
DOUBLE = str(HERE / "models" / "double_pendulum.py")
PENDULUM = str(HERE / "models" / "vertical_pendulum.py")
OMEGA = 2 * math.pi
SAMPLES = 16


def _structurally_orthogonal(pattern: np.ndarray, colours: tuple) -> bool:
    return all(int(np.max(pattern[:, c].sum(axis=1), initial=0)) <= 1 for c in colours)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.integers(0, 2**31 - 1))
def test_colouring_is_a_structurally_orthogonal_partition(rows, cols, seed):
    P = np.random.default_rng(seed).random((rows, cols)) < 0.3
    colours = cs.colour_columns(P)
    assert sorted(np.concatenate(colours).tolist()) == list(range(cols))
    assert _structurally_orthogonal(P, colours)


def test_colouring_of_a_band_needs_its_width_only():
    # a tridiagonal band of 4-coordinate nodes (ANCF chain): rows of node i touch nodes i-1..i+1
    nodes, w = 30, 4
    P = np.zeros((nodes * w, nodes * w), dtype=bool)
    for i in range(nodes):
        for j in range(max(0, i - 1), min(nodes, i + 2)):
            P[i * w:(i + 1) * w, j * w:(j + 1) * w] = True
    colours = cs.colour_columns(P)
    assert _structurally_orthogonal(P, colours)
    assert len(colours) == 3 * w  # columns of nodes i, i+3, i+6, ... share no row
    # a wrong "colouring" (two neighbours together) is caught by the same predicate
    assert not _structurally_orthogonal(P, (np.array([0, w]),))


@pytest.fixture(scope="module")
def double_orbits():
    dense = find_orbit(DOUBLE, OMEGA, samples=SAMPLES, verify=False, solver="dense")
    structured = find_orbit(DOUBLE, OMEGA, samples=SAMPLES, verify=False, solver="structured")
    return dense, structured


def _dense_collocation(orbit):
    col = po._Collocation(build_model(orbit.model, orbit.omega), orbit.samples, "dense")
    X = np.concatenate([orbit.q, orbit.lambdas, orbit.torques], axis=1)
    return col, X


def test_structured_orbit_satisfies_the_dense_equations(double_orbits):
    dense, structured = double_orbits
    assert structured.residual <= structured.tolerance
    col, X = _dense_collocation(structured)
    out, fscale = col.residual(X)
    res = col.relative(out, fscale, max(1.0, float(np.max(np.abs(structured.q)))))
    assert res <= structured.tolerance  # the dense route's residual, not the structured solver's
    # Same orbit: the difference of two solutions with relative residuals <= tol is
    # <= ||J^-1|| * 2 tol * force scale; here both polish to round-off (~1e-14), so
    # 1e-9 of the coordinate scale is a bound with decades to spare.
    assert np.max(np.abs(structured.q - dense.q)) <= 1e-9 * max(1.0, float(np.max(np.abs(dense.q))))
    assert np.max(np.abs(structured.torques - dense.torques)) <= 1e-9 * float(np.max(np.abs(dense.torques)))


def test_compressed_blocks_equal_dense_differences(double_orbits):
    _, orbit = double_orbits
    args = _tangent_args(orbit)
    dense_tb = _per_column_blocks(*args)  # one difference per column
    pattern = cs.coupling_pattern(args[0])
    sb = cs.compressed_blocks(*args, pattern, derivative=po._richardson,
                              steps=lambda x: po.fd_steps(x, po.RICHARDSON_STEP))
    # same difference rule and steps; only the round-off of evaluating several
    # perturbed columns at once differs: eps |f| / h ~ 1e-16 / 1e-4 ~ 1e-12 relative
    for name in ("M", "K_force", "K_reaction", "C", "Cq"):
        a, b = getattr(dense_tb, name), getattr(sb, name)
        assert np.max(np.abs(a - b)) <= 1e-8 * max(float(np.max(np.abs(a))), 1e-300), name


def _per_column_blocks(system, times, Q, V, A, L):
    """tangent_blocks with one Richardson difference per force column (no pattern)."""
    tb = po.tangent_blocks(system, times, Q, V, A, L, use_exudyn_jacobian=False)
    const_mass = system.mass_is_constant(Q[0])
    Kf, Cd = np.empty_like(tb.K_force), np.empty_like(tb.C)
    for k in range(times.size):
        Kf[k], Cd[k] = po._force_fd(system, Q[k], V[k], A[k], float(times[k]), po.RICHARDSON_STEP, const_mass)
    return po.TangentBlocks(M=tb.M, K_force=Kf, K_reaction=tb.K_reaction, C=Cd, Cq=tb.Cq)


def _tangent_args(orbit):
    col = po._Collocation(build_model(orbit.model, orbit.omega), orbit.samples, "dense")
    return col.system, col.times, orbit.q, orbit.q_t, orbit.q_tt, orbit.lambdas


def test_sparse_newton_matrix_equals_dense_assembly(double_orbits):
    _, orbit = double_orbits
    col, X = _dense_collocation(orbit)
    J_dense, tb = col.jacobian(X)
    J_sparse = cs.sparse_newton_matrix(tb.M, tb.K, tb.C, tb.Cq, col.B, col.D1, col.D2)
    assert J_sparse.shape == J_dense.shape
    assert np.max(np.abs(J_sparse.toarray() - J_dense)) <= 1e-14 * np.max(np.abs(J_dense))
    r = np.random.default_rng(0).standard_normal(J_dense.shape[0])
    x = cs.sparse_solver(J_sparse)(r)
    assert np.max(np.abs(J_dense @ x - r)) <= 1e-9 * np.max(np.abs(r))


def test_cached_assembly_equals_sparse_newton_matrix_and_rebuilds_on_a_new_pattern(double_orbits):
    """NewtonAssembly (structure kept between calls) gives sparse_newton_matrix's matrix (itself
    checked against the dense assembly above) entry for entry; when a block gains an entry
    outside the cached pattern it must rebuild (a stale structure would drop the entry)."""
    _, orbit = double_orbits
    col, X = _dense_collocation(orbit)
    _, tb = col.jacobian(X)
    asm = cs.NewtonAssembly(col.B, col.D1, col.D2)
    for scale in (1.0, 1.5):  # second call: same pattern, new values, reused structure
        K = scale * tb.K
        ref = cs.sparse_newton_matrix(tb.M, K, tb.C, tb.Cq, col.B, col.D1, col.D2)
        got = asm(tb.M, K, tb.C, tb.Cq)
        assert abs(got - ref).max() == 0.0
    assert asm.builds == 1
    i, j = np.argwhere((tb.K[0] == 0) & (tb.M[0] == 0) & (tb.C[0] == 0))[0]
    K = tb.K.copy()
    K[:, i, j] = 1.0  # a new coupling
    ref = cs.sparse_newton_matrix(tb.M, K, tb.C, tb.Cq, col.B, col.D1, col.D2)
    got = asm(tb.M, K, tb.C, tb.Cq)
    assert asm.builds == 2
    assert abs(got - ref).max() == 0.0
    # an entry dropping to zero stays inside the structure: no rebuild, the same values
    K[:, i, j] = 0.0
    ref = cs.sparse_newton_matrix(tb.M, K, tb.C, tb.Cq, col.B, col.D1, col.D2)
    got = asm(tb.M, K, tb.C, tb.Cq)
    assert asm.builds == 2
    assert abs(got - ref).max() == 0.0


def test_pattern_missing_a_coupling_is_rejected(double_orbits):
    _, orbit = double_orbits
    system, times, Q, V, A, L = _tangent_args(orbit)
    pattern = cs.coupling_pattern(system)
    eye = np.eye(system.n, dtype=bool)
    assert np.any(pattern.force & ~eye)  # the pendulum's forces do couple coordinates
    wrong = cs.CouplingPattern(force=eye, reaction=pattern.reaction, force_colours=cs.colour_columns(eye),
                               reaction_colours=pattern.reaction_colours)
    rule = po._richardson
    steps = lambda x: po.fd_steps(x, po.RICHARDSON_STEP)  # noqa: E731
    ok = cs.compressed_blocks(system, times, Q, V, A, L, pattern, derivative=rule, steps=steps)
    assert ok.pattern_mismatch <= cs.PATTERN_CHECK_TOLERANCE
    with pytest.raises(cs.PatternError, match="outside the structural pattern"):
        cs.compressed_blocks(system, times, Q, V, A, L, wrong, derivative=rule, steps=steps)


@pytest.mark.parametrize("factor", [100.0, -1.0])
def test_inconsistent_newton_matrix_fails_loudly(monkeypatch, factor):
    """Newton accepts only the true residual: with a Newton matrix 100x too large (steps 100x
    too short) or of the wrong sign it must end in OrbitConvergenceError with the residuals
    reached, never return an orbit."""
    real = cs.NewtonAssembly.__call__
    monkeypatch.setattr(cs.NewtonAssembly, "__call__", lambda self, *blocks: factor * real(self, *blocks))
    with pytest.raises(OrbitConvergenceError, match="did not converge") as err:
        find_orbit(PENDULUM, 80.0, samples=8, verify=False, solver="structured", continuation=False,
                   max_iterations=6, amplitude=0.05)
    assert min(err.value.residuals) > po.DEFAULT_TOLERANCE
    # the same call with the consistent matrix converges (so the failure is the matrix's)
    monkeypatch.setattr(cs.NewtonAssembly, "__call__", real)
    orbit = find_orbit(PENDULUM, 80.0, samples=8, verify=False, solver="structured", continuation=False,
                       max_iterations=6, amplitude=0.05)
    assert orbit.residual <= orbit.tolerance


def test_unknown_solver_is_rejected():
    with pytest.raises(ValueError, match="solver must be one of"):
        find_orbit(resolve_model(DOUBLE), OMEGA, samples=SAMPLES, verify=False, solver="gmres")


def test_single_link_structured_equals_dense():
    """ANCF link with a clamp (JointGeneric) and a drive: same orbit, same tolerance."""
    opts = dict(samples=16, verify=False, elements=2)
    dense = find_orbit("single-link", OMEGA, solver="dense", **opts)
    struct = find_orbit("single-link", OMEGA, solver="structured", **opts)
    assert struct.residual <= struct.tolerance and dense.residual <= dense.tolerance
    # both Newtons stop at residuals ~1e-9 of the forces; the coordinates of two such
    # solutions differ by <= cond * residual, far below 1e-9 of the 1 m link
    assert np.max(np.abs(struct.q - dense.q)) <= 1e-9
    assert np.max(np.abs(struct.torques - dense.torques)) <= 1e-7 * float(np.max(np.abs(dense.torques)))


# --------------------------------------------------------------------------- row-wise directional check
def _two_scale_function():
    """``f(x) = A x + x^3 / 3`` (elementwise cube) with rows eight decades apart: analytic
    Jacobian ``A + diag(x^2)``, the stand-in for an axial row (1e9) next to a soft one (1)."""
    A = np.array([[2e9, -1e9, 0.0], [0.5, 1.0, 0.25], [0.0, 0.0, 0.0]])
    x = np.array([0.3, -0.7, 1.1])

    def f(y):
        out = A @ y + y ** 3 / 3.0
        out[2] = 5.0  # independent of y (a constant load)
        return out

    J = A + np.diag(x ** 2)
    J[2, 2] = 0.0
    return f, x, J


def test_directional_mismatch_is_row_wise():
    """Against the analytic Jacobian: accepted (mismatch at the rule's error, << tol); a defect
    of 1e-6 of the soft row (1e-15 of the largest row: invisible to a global normalisation)
    rejected; an entry of 1e-6 in the constant row (whose only floor is the round-off of
    f_2 = 5: 30 eps 5 / (s |e|) ~ 1e-9 per unit coordinate) rejected, as is one of 1e-300
    where f is exactly 0; no halvings -> None."""
    f, x, J = _two_scale_function()
    e = po.fd_steps(x, po.RICHARDSON_STEP) * np.array([0.9, -0.4, 0.7])
    kw = dict(tol=cs.PATTERN_CHECK_TOLERANCE, order=4)
    assert cs.directional_mismatch(f, x, e, J, po._richardson, **kw) <= 1e-3 * cs.PATTERN_CHECK_TOLERANCE
    soft = J.copy()
    soft[1, 0] += 1e-6 * np.max(np.abs(J[1]))
    assert cs.directional_mismatch(f, x, e, soft, po._richardson, **kw) > cs.PATTERN_CHECK_TOLERANCE
    const = J.copy()
    const[2, 1] = 1e-6
    assert cs.directional_mismatch(f, x, e, const, po._richardson, **kw) > 100 * cs.PATTERN_CHECK_TOLERANCE
    zero = J.copy()
    zero[2, 1] = 1e-300
    assert cs.directional_mismatch(lambda y: f(y) * np.array([1.0, 1.0, 0.0]), x, e, zero, po._richardson,
                                   **kw) > 0.5
    weak = cs.directional_mismatch(lambda y: f(y) * np.array([1.0, 1.0, 0.0]) + np.array([0.0, 0.0, 1e-12 * y[1]]),
                                   x, e, J, po._richardson, **kw)
    assert weak > 1.0
    assert cs.directional_mismatch(f, x, e, J, po._richardson, halvings=0, **kw) is None
