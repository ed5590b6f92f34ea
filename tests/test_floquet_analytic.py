"""The Floquet engine against analytic oracles (tiers 1-3 of STYLE.md).

* constant ``P``: ``Phi(T) = expm(P T)``, multipliers ``exp(lambda_i T)`` from
  eigenvalues chosen in the test;
* a periodic similarity (Lyapunov) transform ``x = L(t) z`` of a constant
  system: the same multipliers, and ``Phi_x(T) = L(0) expm(A T) L(0)^-1``;
* Liouville's formula on random smooth periodic systems (hypothesis), and
  agreement with the paper's procedure (Eqs. 7-8 of the paper, p. 489);
* the undamped Mathieu equation against the transition curves of
  ``scipy.special.mathieu_a`` / ``mathieu_b``;
* the measured convergence order of ``magnus6`` and ``magnus4`` against an
  independent tight-tolerance ``solve_ivp`` reference;
* bad input.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import linear_sum_assignment
from scipy.special import mathieu_a, mathieu_b

from stability import SecondOrderPeriodicSystem, floquet
from stability.reference import ReferenceOptions, paper_monodromy

EPS = np.finfo(float).eps


# --------------------------------------------------------------------------- helpers
def _real_matrix_with_eigenvalues(eigs, seed):
    """A real, non-normal matrix with the given eigenvalues (complex ones in conjugate pairs)."""
    blocks = []
    for lam in eigs:
        if abs(lam.imag) > 0 and lam.imag < 0:
            continue
        if lam.imag > 0:
            blocks.append(np.array([[lam.real, lam.imag], [-lam.imag, lam.real]]))
        else:
            blocks.append(np.array([[lam.real]]))
    n = sum(b.shape[0] for b in blocks)
    D = np.zeros((n, n))
    i = 0
    for b in blocks:
        k = b.shape[0]
        D[i : i + k, i : i + k] = b
        i += k
    rng = np.random.default_rng(seed)
    V = np.eye(n) + 0.3 * rng.standard_normal((n, n))  # cond(V) ~ 2-5
    return V @ D @ np.linalg.inv(V), np.linalg.cond(V)


def _match(a, b):
    """Pair up two multiplier sets (minimum total distance) -> (a_sorted, b_matched)."""
    cost = np.abs(a[:, None] - b[None, :])
    r, c = linear_sum_assignment(cost)
    return a[r], b[c]


def _max_backward_error(Phi_ref, rhos):
    """max_i sigma_min(Phi_ref - rho_i I) / ||Phi_ref||: each rho_i is an exact
    eigenvalue of a matrix that close to Phi_ref.  Unlike a forward comparison
    this stays meaningful for (near-)multiple multipliers."""
    n = Phi_ref.shape[0]
    norm = np.linalg.norm(Phi_ref, 2)
    return max(
        np.linalg.svd(Phi_ref - r * np.eye(n), compute_uv=False)[-1] for r in rhos
    ) / norm


# --------------------------------------------------------------------------- constant P
CONSTANT_CASES = {
    # name: (eigenvalues, period, expected verdict)
    "stable": ([-0.3 + 2.0j, -0.3 - 2.0j, -1.0, -0.05], 2.0, "asymptotically stable"),
    "unstable": ([0.5, -0.2 + 3.0j, -0.2 - 3.0j, -2.0], 2.0, "unstable"),
    # eigenvalue -3000 1/s (the controlled manipulator has one near -3300);
    # T chosen so that exp(-3000 T) = 3e-7 is still above the noise floor
    # (|rho| = exp(-0.1 T) = 0.9995: decays by e only in 2000 periods, above the 1000 of the verdict
    # rule of stability.verdict -> critical, not asymptotically stable)
    "stiff": ([-3000.0, -1.0, -0.1 + 5.0j, -0.1 - 5.0j], 0.005, "critical"),
    # undamped oscillator pair (|rho| = 1 exactly) plus a lightly damped one
    "oscillatory": ([20.0j, -20.0j, -0.01 + 7.0j, -0.01 - 7.0j], 1.3, "critical"),
}


def _constant_P_bounds(A, T, cond_V, n_factors, noise_floor):
    """Rounding bounds for ``P = A = V D V^-1`` constant (D normal: real 2x2 rotation blocks).

    The Magnus exponent of a constant ``P`` is exactly ``h A``, so every error is rounding:

    * ``phi``: ``||fl(E^N) - Phi|| <= N cond(V)^3 noise_floor``.  Each factor
      ``E = V e^{Dh} V^-1`` is formed to ``n eps ||E||`` and ``||E^j|| <= cond(V) sigma^j``
      (``sigma = max |e^{lambda h}|``), so the k-th error reaches the product as
      ``||E^{N-k}|| n eps ||E|| ||E^{k-1}|| <= n eps cond(V)^3 rho_max``, and
      ``noise_floor = n eps ||Phi|| >= n eps rho_max``;
    * ``multiplier`` (absolute): ``cond(V) (phi + noise_floor)``: Bauer-Fike with
      ``cond(V)``, plus LAPACK's eigenvalue backward error ``<= n eps ||Phi||``;
    * ``trace``: ``T n (2 n + 2) eps cond(V) max|lambda|``: forming ``V D V^-1`` moves the
      eigenvalues (and so ``tr A``) by ``<= 2 n eps cond(V) max|lambda|`` each, the
      trapezoidal sum of a constant adds ``<= log2(TRACE_POINTS) eps`` relative;
    * ``liouville``: ``sum_i multiplier / |rho_i| + trace`` (first order in
      ``ln|det Phi| - int tr P``).

    ``n_factors`` and ``noise_floor`` are what the result reports (``res.n_steps``,
    ``res.noise_floor``); the test checks the latter against ``n eps ||expm(A T)||``.
    """
    eigs = np.linalg.eigvals(A)
    n = A.shape[0]
    rho = np.abs(np.exp(eigs * T))
    phi = n_factors * cond_V**3 * noise_floor
    multiplier = cond_V * (phi + noise_floor)
    trace = T * n * (2 * n + 2 + math.log2(512)) * EPS * cond_V * np.abs(eigs).max()
    with np.errstate(divide="ignore"):  # an underflowing multiplier: no Liouville bound (inf)
        liouville = float(np.sum(multiplier / rho)) + trace
    return {"phi": phi, "multiplier": multiplier, "trace": trace, "liouville": liouville}


def _constant_P_setup(case):
    eigs, T, verdict = CONSTANT_CASES[case]
    A, condV = _real_matrix_with_eigenvalues(np.array(eigs, dtype=complex), seed=len(case))
    return np.array(eigs, dtype=complex), T, verdict, A, condV


@pytest.mark.parametrize("method", ["magnus6", "magnus4"])
@pytest.mark.parametrize("case", sorted(CONSTANT_CASES))
def test_constant_P(case, method, magnus_path):
    eigs, T, verdict, A, condV = _constant_P_setup(case)
    res = floquet(lambda t: A, period=T, method=method)
    Phi = expm(A * T)
    expected = np.exp(eigs * T)
    n = A.shape[0]
    # the reported noise floor is n eps ||Phi|| of the true monodromy; ||Phi|| is off by
    # <= bound["phi"] / ||Phi|| < 1e-10 relative in these cases, so rel=1e-6 is safe
    assert res.noise_floor == pytest.approx(n * EPS * np.linalg.norm(Phi, 2), rel=1e-6)
    bound = _constant_P_bounds(A, T, condV, res.n_steps, res.noise_floor)
    got, exp_ = _match(res.multipliers, expected)
    np.testing.assert_allclose(got, exp_, rtol=0, atol=bound["multiplier"])
    # the oracle expm(A T) (Pade 13, s = ceil(log2(||A T||_1 / 5.37)) <= 4 squarings here)
    # carries <= (s + 1) n eps ||Phi|| <= 5 noise floors; 10 leaves room for s <= 9
    np.testing.assert_allclose(res.monodromy, Phi, rtol=0, atol=bound["phi"] + 10 * res.noise_floor)
    # sorted by modulus, descending (ties of a conjugate pair are exact); spectral radius first
    assert np.all(np.diff(np.abs(res.multipliers)) <= 2 * EPS * np.abs(res.multipliers[:-1]))
    assert abs(res.spectral_radius - np.abs(expected).max()) <= bound["multiplier"]
    assert res.verdict == verdict
    # Liouville: det expm(AT) = exp(T tr A) = exp(T sum(eigs))
    assert abs(res.trace_integral - T * np.sum(eigs).real) <= bound["trace"]
    # The smallest multiplier (3e-7 in "stiff") is read from Phi to an absolute
    # cond(V)(N cond(V)^3 + 1) noise_floor, so ln|rho| relative to it: see _constant_P_bounds.
    assert res.liouville_residual <= bound["liouville"]
    assert res.multiplier_liouville_residual <= bound["liouville"]


class _ConstantWithTrace:
    """``P(t) = A`` with a closed-form ``trace_integral`` (as models supply it)."""

    def __init__(self, A, period, trace):
        self.A, self.period, self._trace = A, period, trace

    def __call__(self, t):
        return self.A

    def trace_integral(self):
        return self._trace


@pytest.mark.parametrize("case", sorted(CONSTANT_CASES))
def test_constant_P_bounds_reject_wrong_answers(case):
    """The derived bounds are tight enough to reject (a) the monodromy of ``A (1 + 1e-6)``
    (relative error 1e-6 in every exponent, checked against the true ``int tr P``)
    and (b) a trace integral wrong by 1e-6 relative.  (The Liouville bound of "stiff"
    is 7e-6: ``ln`` of its 3e-7 multiplier read from ``Phi`` is no better; the
    multiplier and monodromy bounds reject (a) by four orders more.)"""
    eigs, T, _, A, condV = _constant_P_setup(case)
    true_trace = T * float(np.sum(eigs).real)
    expected = np.exp(eigs * T)
    # (a) perturbed monodromy
    res = floquet(_ConstantWithTrace(A * (1 + 1e-6), T, true_trace))
    bound = _constant_P_bounds(A, T, condV, res.n_steps, res.noise_floor)
    got, exp_ = _match(res.multipliers, expected)
    assert np.max(np.abs(got - exp_)) > bound["multiplier"]
    assert np.linalg.norm(res.monodromy - expm(A * T), 2) > bound["phi"]
    if case != "oscillatory":  # T tr A = -0.026: ln det moves by 2.6e-8 only
        assert res.liouville_residual > bound["liouville"]
    # (b) wrong trace integral with the right monodromy
    wrong = true_trace + 1e-6 * max(1.0, abs(true_trace))
    res = floquet(_ConstantWithTrace(A, T, wrong))
    bound = _constant_P_bounds(A, T, condV, res.n_steps, res.noise_floor)
    assert abs(res.trace_integral - true_trace) > bound["trace"]
    assert res.liouville_residual > bound["liouville"]


def test_constant_P_underflowing_stiff_multiplier_is_flagged():
    """With T = 1 the stiff multiplier exp(-3000) underflows: the result must flag it as noise."""
    eigs = np.array([-3000.0, -1.0, -0.1 + 5.0j, -0.1 - 5.0j])
    A, cond_V = _real_matrix_with_eigenvalues(eigs, seed=5)
    res = floquet(lambda t: A, period=1.0)
    expected = np.exp(eigs[1:] * 1.0)
    got, exp_ = _match(res.multipliers[:3], expected)
    bound = _constant_P_bounds(A, 1.0, cond_V, res.n_steps, res.noise_floor)
    np.testing.assert_allclose(got, exp_, rtol=0, atol=bound["multiplier"])
    # the smallest modulus is rounding noise of the formed product: flagged
    assert res.moduli[-1] <= 100 * res.noise_floor
    assert res.reliable_digits[-1] == 0
    assert np.all(res.reliable_digits[:3] >= 8)
    assert math.isnan(res.multiplier_liouville_residual)
    assert res.verdict == "asymptotically stable"


def test_liouville_log_form_with_underflowing_factor_determinant():
    """Regression: ln det Phi used to be accumulated from slogdet of
    each factor expm(h A), which is rounding noise when exp(lambda h) < eps
    (exp(-3000/64) = 4e-21); the residual came out as ~1e301."""
    V = np.array([[1.0, 1.0], [1.0, 2.0]])
    A = V @ np.diag([-3000.0, -1.0]) @ np.linalg.inv(V)
    res = floquet(lambda t: A, period=1.0)
    bound = _constant_P_bounds(A, 1.0, np.linalg.cond(V), res.n_steps, res.noise_floor)
    # the multipliers are right (exp(-1) and a flagged ~0) ...
    assert abs(res.multipliers[0] - math.exp(-1.0)) <= bound["multiplier"]
    assert abs(res.trace_integral + 3001.0) <= bound["trace"]
    # ... and det Phi = exp(-3001) exactly, so the log-form residual should be ~1e-12
    assert res.liouville_residual <= 1e-8


# --------------------------------------------------------------------------- similarity transform
class _Transformed:
    """P(t) = L' L^-1 + L A L^-1 for x = L(t) z, z' = A z.

    L(t) = blockdiag(R(w t), R(2 w t)) diag(1 + 0.3 sin(w t + phi_i)), w = 2 pi / T,
    with R a plane rotation: T-periodic and invertible (diagonal >= 0.7).
    """

    PHASES = np.array([0.0, 1.0, 2.0, 3.0])

    def __init__(self, A, period):
        self.A = A
        self.period = period
        self.w = 2 * math.pi / period

    @staticmethod
    def _rot(theta):
        c, s = math.cos(theta), math.sin(theta)
        return np.array([[c, -s], [s, c]])

    def L_and_dL(self, t):
        w = self.w
        J = np.array([[0.0, -1.0], [1.0, 0.0]])
        R = np.zeros((4, 4))
        dR = np.zeros((4, 4))
        for blk, k in ((slice(0, 2), 1), (slice(2, 4), 2)):
            Rk = self._rot(k * w * t)
            R[blk, blk] = Rk
            dR[blk, blk] = k * w * J @ Rk
        D = np.diag(1.0 + 0.3 * np.sin(w * t + self.PHASES))
        dD = np.diag(0.3 * w * np.cos(w * t + self.PHASES))
        return R @ D, dR @ D + R @ dD

    def __call__(self, t):
        L, dL = self.L_and_dL(t)
        Linv = np.linalg.inv(L)
        return dL @ Linv + L @ self.A @ Linv


@pytest.mark.parametrize("method", ["magnus6", "magnus4"])
@pytest.mark.parametrize(
    "eigs, T",
    [
        ([-0.2 + 1.5j, -0.2 - 1.5j, 0.3, -1.0], 2.0),  # unstable, non-normal A
        ([-0.5 + 4.0j, -0.5 - 4.0j, -0.1 + 1.0j, -0.1 - 1.0j], 1.0),  # stable, complex
    ],
)
def test_periodic_similarity_transform(eigs, T, method, magnus_path):
    eigs = np.array(eigs, dtype=complex)
    A, _ = _real_matrix_with_eigenvalues(eigs, seed=11)
    P = _Transformed(A, T)
    # complex multipliers are compared, so the refinement must certify phases too
    res = floquet(P, method=method, accuracy="multipliers")
    # Discretisation: the actual error is within 10x the step-doubling estimate the result
    # reports (asymptotic regime; measured ratio ~1 here, and test_convergence_order checks the
    # 10x on an independent reference); the adaptive loop stops at estimate <= rtol = 1e-9, so
    # this is never looser than 1e-8.  Rounding: N products, each ~ noise_floor = n eps ||Phi||.
    expected = np.exp(eigs * T)
    got, exp_ = _match(res.multipliers, expected)
    tol = 10 * res.error_estimate * np.abs(expected).max() + res.n_steps * res.noise_floor
    np.testing.assert_allclose(got, exp_, rtol=0, atol=tol)
    L0 = P.L_and_dL(0.0)[0]
    Phi = L0 @ expm(A * T) @ np.linalg.inv(L0)
    np.testing.assert_allclose(res.monodromy, Phi, rtol=0,
                               atol=10 * res.error_estimate * np.linalg.norm(Phi) + res.n_steps * res.noise_floor)
    # tr(L' L^-1) integrates to ln det L(T) - ln det L(0) = 0, so int tr P = T tr A.  The periodic
    # trapezoidal rule is spectrally exact here (ln det L has Fourier coefficients ~ 0.16^k); left is
    # the rounding of a 512-term sum, <= log2(512) eps T max|tr P| ~ 1e-13
    assert res.trace_integral == pytest.approx(T * float(np.trace(A)), abs=1e-10)
    assert res.multiplier_liouville_residual <= 1e-8
    assert res.error_estimate <= 1e-9  # the default rtol


# --------------------------------------------------------------------------- Liouville (hypothesis)
def _fourier_P(coef, T):
    """P(t) = C0 + C1 cos wt + C2 sin wt + C3 cos 2wt + C4 sin 2wt."""
    w = 2 * math.pi / T

    def P(t):
        return (
            coef[0]
            + coef[1] * math.cos(w * t)
            + coef[2] * math.sin(w * t)
            + coef[3] * math.cos(2 * w * t)
            + coef[4] * math.sin(2 * w * t)
        )

    return P


@st.composite
def _periodic_systems(draw):
    n = draw(st.integers(2, 4))
    elems = st.floats(-1.0, 1.0, allow_nan=False, allow_infinity=False)
    coef = draw(arrays(np.float64, (5, n, n), elements=elems))
    coef[1:] *= 0.5  # harmonics somewhat smaller than the mean
    T = draw(st.floats(0.5, 1.5))
    return coef, T


#: The paper's procedure (Eqs. 7-8) with an explicit 8th-order integrator at tight
#: tolerance: independent of the Magnus code and ~50x faster than the default
#: Radau of ``method="paper"`` on these non-stiff systems.
_REFERENCE = ReferenceOptions(integrator="DOP853", rtol=1e-12, atol=1e-14)


@settings(max_examples=15, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(_periodic_systems())
def test_liouville_random_periodic_systems(system):
    coef, T = system
    P = _fourier_P(coef, T)
    res = floquet(P, period=T)
    # independent oracle: int_0^T tr P dt = T tr C0 (the harmonics integrate to 0)
    trace = T * float(np.trace(coef[0]))
    assert res.trace_integral == pytest.approx(trace, abs=1e-11 * max(1.0, abs(trace)))
    # Liouville on the factors (log form) and on the multipliers themselves.  1e-8 is the
    # package's acceptance bound, not a rounding bound: the moduli are within 10x their
    # step-doubling estimate (<= 2.4e-10 on these examples) and sum ln|rho_i| = ln|det Phi| is
    # insensitive to (near-)multiple multipliers; rounding adds ~ N n eps = 3e-14 (measured <= 1.4e-14)
    assert res.liouville_residual <= 1e-8
    if math.isnan(res.multiplier_liouville_residual):
        # only allowed when a multiplier is genuinely below the noise floor
        assert res.moduli[-1] <= 100 * res.noise_floor
    else:
        assert abs(math.expm1(float(np.sum(res.log_moduli)) - trace)) <= 1e-8
        assert res.multiplier_liouville_residual <= 1e-8
    # the paper's procedure: DOP853 at rtol 1e-12 is accurate to ~1e-10 here
    Phi_ref, _ = paper_monodromy(P, T, _REFERENCE)
    np.testing.assert_allclose(res.monodromy, Phi_ref, rtol=0, atol=1e-8 * np.linalg.norm(Phi_ref))
    assert _max_backward_error(Phi_ref, res.multipliers) <= 1e-8


def test_paper_method_agrees_on_a_random_system():
    """``method="paper"`` (Radau, rtol 1e-11) vs magnus6 on one random 2x2 system (~1 s)."""
    rng = np.random.default_rng(7)
    coef = rng.uniform(-1.0, 1.0, (5, 2, 2))
    coef[1:] *= 0.5
    P = _fourier_P(coef, 1.2)
    ours = floquet(P, period=1.2)
    ref = floquet(P, period=1.2, method="paper", error_estimate=False)
    got, exp_ = _match(ours.multipliers, ref.multipliers)
    # both claim ~1e-10; 1e-8 relative to the spectral radius
    np.testing.assert_allclose(got, exp_, rtol=0, atol=1e-8 * ref.spectral_radius)
    assert ref.multiplier_liouville_residual <= 1e-8


# --------------------------------------------------------------------------- Mathieu
def _mathieu(a, q):
    """y'' + (a - 2 q cos 2t) y = 0 as x' = P(t) x, period pi."""

    def P(t):
        return np.array([[0.0, 1.0], [-(a - 2.0 * q * math.cos(2.0 * t)), 0.0]])

    return P


#: Distance from a transition curve; the tongues/stable bands for q <= 2, r <= 2
#: are >= 0.4 wide (b2(1) - a1(1) = 2.06, a2(1) - b2(1) = 0.50, a1 - b1 >= 1.9).
DELTA = 0.05


def _mathieu_points():
    """(q, a, expected verdict, sign of the dominant multiplier when unstable).

    For q > 0: a0 < b1 < a1 < b2 < a2 < ...; the unstable tongues are a < a0 and
    b_r < a < a_r (r >= 1), the stable bands a_r < a < b_{r+1}.  On curves of odd
    index the solutions are 2pi-periodic (multiplier -1), of even index
    pi-periodic (multiplier +1).  Undamped: det Phi = 1, so in the stable bands
    both multipliers lie on the unit circle -> the verdict is "critical".
    """
    pts = []
    for q in (1.0, 2.0):
        a0 = float(mathieu_a(0, q))
        pts += [(q, a0 - DELTA, "unstable", +1), (q, a0 + DELTA, "critical", 0)]
        for r in (1, 2):
            ar, br = float(mathieu_a(r, q)), float(mathieu_b(r, q))
            sign = (-1) ** r
            pts += [
                (q, br - DELTA, "critical", 0),
                (q, br + DELTA, "unstable", sign),
                (q, ar - DELTA, "unstable", sign),
                (q, ar + DELTA, "critical", 0),
            ]
    return pts


@pytest.mark.parametrize("q, a, verdict, sign", _mathieu_points())
def test_mathieu_verdicts(q, a, verdict, sign):
    res = floquet(_mathieu(a, q), period=math.pi)
    assert res.verdict == verdict
    # Hamiltonian: rho1 rho2 = 1 exactly (tr P = 0)
    assert abs(np.prod(res.multipliers) - 1.0) <= 1e-9
    if verdict == "critical":
        np.testing.assert_allclose(res.moduli, 1.0, atol=1e-9)
    else:
        rho = res.multipliers[0]
        assert abs(rho.imag) <= 1e-9 and np.sign(rho.real) == sign
        assert res.spectral_radius > 1.05  # well outside the critical band


@pytest.mark.parametrize("q", [1.0, 2.0])
@pytest.mark.parametrize("kind, r", [("a", 0), ("a", 1), ("b", 1), ("a", 2), ("b", 2)])
def test_mathieu_on_transition_curves(q, kind, r, magnus_path):
    """On a_r(q), b_r(q) the Hill discriminant tr Phi(pi) equals 2 (-1)^r."""
    a = float((mathieu_a if kind == "a" else mathieu_b)(r, q))
    # fixed N = 512 (h = pi/512, ||P|| <= 7: magnus6 error ~1e-14); the adaptive default is
    # tested on the curves below
    res = floquet(_mathieu(a, q), period=math.pi, n_steps=512)
    # scipy's characteristic values are good to ~1e-9 here and d(tr Phi)/da = O(1..10)
    assert np.trace(res.monodromy) == pytest.approx(2.0 * (-1) ** r, abs=1e-7)


def test_mathieu_on_transition_curve_is_a_named_defective_pair_and_its_bound_covers(magnus_path):
    """On a_0(q) the multiplier +1 is double and defective (a Jordan block): its error is the square
    root of the monodromy error.  The default names the pair in a warning, and the estimate (the
    Henrici square-root bound) covers the true error; the first-order Richardson estimate of the
    eigenvalues does not (it is what the estimate was before the conditioning rule)."""
    a = float(mathieu_a(0, 1.0))
    with pytest.warns(RuntimeWarning, match="defective or clustered"):
        res = floquet(_mathieu(a, 1.0), period=math.pi)
    assert res.n_steps <= 4096
    # exact: both multipliers are +1 (scipy's a_0 is good to ~1e-12 here: its share of the error
    # is sqrt(1e-12 * |d tr Phi / da|) ~ 1e-6 at most, included below)
    err = np.max(np.abs(res.multipliers - 1.0))
    a_share = math.sqrt(1e-12 * 10.0)
    assert err <= res.error_estimate + a_share
    # the rule matters: a first-order estimate from two plain solves is far below the error
    N = res.n_steps
    fine, coarse = floquet(_mathieu(a, 1.0), period=math.pi, n_steps=N, error_estimate=False), \
        floquet(_mathieu(a, 1.0), period=math.pi, n_steps=N // 2, error_estimate=False)
    first_order = np.max(np.abs(np.sort_complex(fine.multipliers) - np.sort_complex(coarse.multipliers))) / 63.0
    assert first_order < err


# --------------------------------------------------------------------------- convergence order
_rng = np.random.default_rng(3)
_C = [_rng.standard_normal((3, 3)) for _ in range(3)]  # generic: non-commuting


def _smooth_P(t):
    w = 2 * math.pi
    return _C[0] + 2.0 * _C[1] * math.cos(w * t) + 2.0 * _C[2] * math.sin(2 * w * t)



@pytest.fixture(scope="module")
def smooth_reference():
    # independent reference: DOP853 on the matrix ODE at rtol 1e-13 (error ~1e-12,
    # below the smallest Magnus error used in the fit, 5e-10)
    sol = solve_ivp(
        lambda t, y: (_smooth_P(t) @ y.reshape(3, 3)).ravel(),
        (0.0, 1.0), np.eye(3).ravel(), method="DOP853", rtol=1e-13, atol=1e-16,
    )
    assert sol.success
    return sol.y[:, -1].reshape(3, 3)


@pytest.mark.parametrize("method, order, Ns", [("magnus6", 6, [8, 16, 32, 64]), ("magnus4", 4, [16, 32, 64, 128, 256])])
def test_convergence_order(method, order, Ns, smooth_reference, magnus_path):
    ref = smooth_reference
    errs = []
    for N in Ns:
        res = floquet(_smooth_P, period=1.0, method=method, n_steps=N, error_estimate=False)
        assert res.n_steps == N
        errs.append(np.linalg.norm(res.monodromy - ref) / np.linalg.norm(ref))
    slope = -np.polyfit(np.log(Ns), np.log(errs), 1)[0]
    assert abs(slope - order) <= 0.7, (errs, slope)
    # the Richardson estimate of the default (adaptive) run is honest: the actual
    # modulus error is below 10x the estimate, and below rtol
    res = floquet(_smooth_P, period=1.0, method=method)
    ref_moduli = np.sort(np.abs(np.linalg.eigvals(ref)))[::-1]
    err = np.max(np.abs(res.moduli / ref_moduli - 1.0))
    assert err <= max(10 * res.error_estimate, 1e-11)
    assert err <= 1e-9


# --------------------------------------------------------------------------- bad input
def _good(t):
    return np.array([[0.0, 1.0], [-1.0, -0.1]])


@pytest.mark.parametrize(
    "P, pattern",
    [
        (lambda t: np.zeros((2, 3)), r"square"),
        (lambda t: np.zeros(3), r"square"),
        (lambda t: 1.0, r"square"),
        (lambda t: np.zeros((2, 2)) if t == 0.0 else np.zeros((3, 3)), r"shape"),
        (lambda t: np.array([[0.0, 1.0], [np.nan, 0.0]]), r"NaN or inf"),
        (lambda t: np.array([[0.0, 1.0], [np.inf, 0.0]]), r"NaN or inf"),
        # finite at t = 0 (first check) but not later
        (lambda t: _good(t) * (np.nan if t > 0.3 else 1.0), r"NaN or inf"),
        ("not callable", r"callable"),
    ],
)
def test_bad_P(P, pattern):
    with pytest.raises(ValueError, match=pattern):
        floquet(P, period=1.0)


@pytest.mark.parametrize("period", [0.0, -1.0, math.nan, math.inf, "one"])
def test_bad_period(period):
    with pytest.raises(ValueError, match=r"period"):
        floquet(_good, period=period)


def test_missing_period():
    with pytest.raises(ValueError, match=r"period"):
        floquet(_good)


def test_unknown_method():
    with pytest.raises(ValueError, match=r"unknown method 'rk4'.*magnus6"):
        floquet(_good, period=1.0, method="rk4")


@pytest.mark.parametrize("kwargs, pattern", [
    ({"n_steps": 0}, "n_steps"), ({"n_steps": 2.5}, "n_steps"),
    ({"rtol": 0.0}, "rtol"), ({"rtol": math.nan}, "rtol"),
    ({"stability_tol": -1.0}, "stability_tol"),
])
def test_bad_options(kwargs, pattern):
    with pytest.raises(ValueError, match=pattern):
        floquet(_good, period=1.0, **kwargs)


def test_singular_mass_matrix():
    sys = SecondOrderPeriodicSystem(
        period=1.0,
        mass=lambda t: np.array([[1.0, 2.0], [2.0, 4.0]]),  # rank 1
        damping=lambda t: np.eye(2),
        stiffness=lambda t: np.eye(2),
    )
    with pytest.raises(ValueError, match=r"mass matrix.*singular"):
        floquet(sys)


def test_mass_matrix_singular_at_some_time():
    sys = SecondOrderPeriodicSystem(
        period=1.0,
        # regular at t = 0 (where P is first probed), singular on (0.3, 0.7)
        mass=lambda t: np.diag([1.0, 0.0 if 0.3 < t < 0.7 else 1.0]),
        damping=lambda t: np.eye(2),
        stiffness=lambda t: np.eye(2),
    )
    with pytest.raises(ValueError, match=r"mass matrix.*singular"):
        floquet(sys)


@pytest.mark.parametrize("period", [0.0, -2.0, math.nan])
def test_second_order_system_bad_period(period):
    with pytest.raises(ValueError, match="period"):
        SecondOrderPeriodicSystem(period, lambda t: np.eye(1), lambda t: np.eye(1), lambda t: np.eye(1))


def test_second_order_system_matches_hand_built_P():
    """Mass-spring-damper with periodic stiffness: P built by hand vs the system."""
    m, c = 2.0, 0.3
    sys = SecondOrderPeriodicSystem(
        period=math.pi,
        mass=lambda t: np.array([[m]]),
        damping=lambda t: np.array([[c]]),
        stiffness=lambda t: np.array([[3.0 + math.cos(2 * t)]]),
    )
    res = floquet(sys)
    ref = floquet(lambda t: np.array([[0.0, 1.0], [-(3.0 + math.cos(2 * t)) / m, -c / m]]), period=math.pi)
    # the same P up to rounding of M^-1 K (m = 2: exact); equal to rounding when both adaptive runs stop
    # at the same step count, else each within 10x its step-doubling estimate
    tol = 1e-12 if res.n_steps == ref.n_steps else 10 * (res.error_estimate + ref.error_estimate)
    np.testing.assert_allclose(res.multipliers, ref.multipliers, rtol=tol)
    # Liouville: det Phi = exp(-c/m T)
    assert np.prod(res.moduli) == pytest.approx(math.exp(-c / m * math.pi), rel=1e-9)
