"""Robustness of the Floquet engine.

Oracles: an independent scheme (4th-order Magnus at a fixed, fine step count,
with its own step-halving estimate), so that the adaptive default is checked
against a computation that shares neither its scheme nor its step selection;
and the error contracts of the command line (one line, exit code 2 for input
that cannot mean anything, 1 for a computation that cannot be completed).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import example, HealthCheck, given, settings
from hypothesis import strategies as st

from flexstab.cli import main as cli_main
from mbs_models.parameters import ManipulatorParameters
from mbs_models.reduced import ReducedModel
from stability import floquet
from stability.floquet import FloquetError

#: Independent reference: magnus4 with a fixed step count (its error ~ C N^-4 is
#: reported by the N/2 comparison and enters the bound below).
REFERENCE_STEPS = 1024
#: Richardson estimates are asymptotic, not rigorous: the adaptive method accepts
#: a pair only when the observed error scaling agrees with the scheme's order
#: within a factor 4 (floquet.CONSISTENCY), so allow 10x the sum of both estimates.
ESTIMATE_FACTOR = 10.0
#: The accuracy the default ``floquet()`` certifies (its ``rtol``).
CERTIFIED_RTOL = 1e-9


def _agree(a, b) -> bool:
    """Moduli >= 1e-6 of the largest agree within the combined error estimates.

    Bound: |rho_a - rho_b| / rho <= 10 (est_a + est_b) + (N_a + N_b) n eps: the step-doubling
    estimates bound the discretisation, and each of the N factors of a product of n x n
    propagators rounds the dominant modulus by ~n eps relative (a fixed 100 eps was too small for
    N = 1024: hypothesis found a 1.0191 multiplier 1e-13 apart with estimates of 5e-15).
    The adaptive result is certified to the requested ``rtol`` (default 1e-9); its Richardson
    estimate can under-read the true error in the pre-asymptotic range (found by hypothesis:
    0.941 m, no tip mass, 4 pi, kp 0, kd 11.11 -> true error 1.9e-11, estimate 6.7e-13, N = 128),
    so the bound is never tighter than that certified ``rtol``.
    The rounding of the product is absolute, ~N n eps rho_max, so relative to a smaller modulus
    rho_i it is N n eps rho_max / rho_i (a CI run found 2.3e-6 next to 1.02 off by 1.7e-8 relative).
    Secondary moduli are compared on the scale of the spectral radius (the scale that decides
    stability): the default's per-multiplier relative estimate is not reliable for them (found:
    1.08 m / 0.473 kg, 4 pi, kp 20.13, kd 17.65 -> the 8.9e-5 modulus off by 4.3e-8 relative,
    3.8e-12 absolute, with an estimate of 1e-10; a known limit of the per-multiplier estimate).
    """
    keep = b.moduli >= 1e-6 * b.moduli[0]
    rho = b.moduli[0]
    rounding = (a.n_steps + b.n_steps) * len(a.moduli) * np.finfo(float).eps * rho
    bound = (max(ESTIMATE_FACTOR * a.error_estimate, CERTIFIED_RTOL) + ESTIMATE_FACTOR * b.error_estimate) * rho
    return bool(np.all(np.abs(a.moduli[keep] - b.moduli[keep]) <= bound + rounding))


def _reference(model):
    return floquet(model, method="magnus4", n_steps=REFERENCE_STEPS)


USER_LINK = ManipulatorParameters(length=0.6, tip_mass=0.3)


@pytest.mark.parametrize("kd", [15.0, 18.0, 21.0])
def test_default_method_on_the_user_link_at_4pi(kd):
    """0.6 m / 0.3 kg at 4 pi, kd 15-21 overflowed the default's first step count."""
    model = ReducedModel(4 * math.pi, 20.0, kd, params=USER_LINK)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no overflow warnings either
        res = floquet(model)
    assert res.error_estimate <= 1e-9
    assert _agree(res, _reference(model))


def test_agreement_check_rejects_a_wrong_answer():
    """The check above fails on a result that is really off: the default's moduli moved by
    1e-7 relative (100x its estimate), and magnus6 with 32 steps (h|lambda| = 87, 4e-4 off)."""
    import dataclasses

    model = ReducedModel(4 * math.pi, 20.0, 18.0, params=USER_LINK)
    ref = _reference(model)
    res = floquet(model)
    assert _agree(res, ref)
    shifted = dataclasses.replace(res, log_moduli=res.log_moduli + 1e-7)
    assert not _agree(shifted, ref)
    coarse = floquet(model, n_steps=32)
    assert abs(coarse.spectral_radius / ref.spectral_radius - 1) > 1e-4
    assert not _agree(dataclasses.replace(coarse, error_estimate=res.error_estimate), ref)


# derandomize: the same examples on every machine and run (the ones found so far are pinned below)
@settings(max_examples=12, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@example(length=0.99999, tip_mass=0.0, k=8, kp=0.0, kd=33.0)  # found by hypothesis: rounding-limited
@example(length=0.9411410533042086, tip_mass=0.0, k=4, kp=0.0, kd=11.113936481144332)  # estimate under-reads
@example(length=1.0, tip_mass=0.0, k=8, kp=0.0, kd=1.0)  # found in a CI run: estimate under-reads
@example(length=1.0, tip_mass=0.0, k=8, kp=0.0, kd=35.0)  # found in a CI run: small modulus, rounding
@example(length=1.0821418587149134, tip_mass=0.4730120584796015, k=4, kp=20.12581366318466,
         kd=17.648661672495763)  # secondary modulus off by 4.3e-8 relative (see _agree)
@given(
    length=st.floats(0.4, 1.4),
    tip_mass=st.floats(0.0, 0.6),
    k=st.sampled_from([2, 4, 6, 8]),
    kp=st.floats(0.0, 60.0),
    kd=st.floats(0.0, 40.0),
)
def test_default_agrees_with_an_independent_scheme_on_random_links(length, tip_mass, k, kp, kd):
    model = ReducedModel(k * math.pi, kp, kd, params=ManipulatorParameters(length=length, tip_mass=tip_mass))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        res = floquet(model)
    ref = _reference(model)
    assert _agree(res, ref), (res.moduli, ref.moduli, res.error_estimate, ref.error_estimate)


def test_stiff_fast_system_fails_fast_with_high_order_magnus():
    """A 40-state system with ||P|| ~ 4e5 1/s (like the Exudyn linearisation) and
    magnus6: a clear error naming magnus2 instead of an endless refinement."""
    rng = np.random.default_rng(0)
    n = 40
    A = rng.standard_normal((n, n)) * 1e3
    A[0, 0] = -4e5
    B = rng.standard_normal((n, n)) * 1e3

    def P(t):
        return A + math.sin(2 * math.pi * t) * B

    with pytest.raises(FloquetError, match="magnus2"):
        floquet(P, period=1.0, method="magnus6")


def test_exact_overflow_is_named():
    """An exponentially growing system beyond double precision in one period."""
    with pytest.raises(FloquetError, match="beyond"):
        floquet(lambda t: np.array([[800.0 + math.sin(6.283185307179586 * t), 0.0], [0.0, -1.0]]), period=1.0)


@pytest.mark.parametrize("argv, code, pattern", [
    (["--omega", "1e-300"], 2, "too long"),
    (["--omega", "1e-6"], 1, "too long"),
    (["--method", "paper", "--small-multipliers", "qr"], 2, "factor method"),
])
def test_cli_one_line_errors(argv, code, pattern, capsys):
    assert cli_main(["floquet", *argv]) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and pattern in err and "Traceback" not in err


def test_cli_table_with_null_log_moduli_and_liouville(capsys):
    """JSON nulls (ln 0, an unavailable Liouville check) print as text, not a traceback."""
    from flexstab.commands.floquet import _table

    d = {
        "model": "reduced", "omega": 2 * math.pi, "period": 1.0, "kp": 1.0, "kd": 1.0,
        "method": "paper", "n_steps": 10, "multipliers": [[0.3, 0.0], [0.0, 0.0]], "moduli": [0.3, 0.0],
        "reliable_digits": [9.0, 0.0], "log_moduli": [math.log(0.3), None], "error_estimate": None,
        "spectral_radius": 0.3, "verdict": "asymptotically stable", "stability_tolerance": 1e-8,
        "liouville_residual": None, "liouville_source": "unavailable",
    }
    text = _table(d)
    assert "n/a" in text and "|rho| = 0" in text


def test_cli_huge_omega_prints_a_table(capsys):
    assert cli_main(["floquet", "--omega", "1e6pi"]) == 0
    out = capsys.readouterr().out
    assert "spectral radius" in out


# --------------------------------------------------------------------------- kernels
@pytest.mark.parametrize("norm", [0.0, 1e-3, 0.5, 0.82, 3.0, 40.0, 700.0])
def test_taylor_expm_of_small_stacks_against_scipy(norm):
    """expm_soa (degree-16 Taylor, scaling and squaring) vs scipy.linalg.expm (Pade, independent).

    Bound: scaling and squaring loses ~ 2^s * eps * cond; Higham (2005) observes
    relative errors ~ 1e-13 at 1-norms ~ 1e3 -> 1e-12 allowed, 1e-15 below the
    unscaled threshold (0.82)."""
    from scipy.linalg import expm

    from stability.expm import expm_soa

    rng = np.random.default_rng(int(norm * 10) + 1)
    A = rng.standard_normal((12, 4, 4))
    A *= norm / max(np.max(np.sum(np.abs(A), axis=1)), 1e-300)
    ref = np.array([expm(a) for a in A])
    got = expm_soa(np.ascontiguousarray(A.transpose(1, 2, 0))).transpose(2, 0, 1)
    tol = 1e-15 * 4 if norm <= 0.82 else 1e-12
    assert np.max(np.abs(got - ref)) <= tol * np.max(np.abs(ref))
    if norm > 10.0:  # rejects a wrong answer: the Taylor polynomial without scaling
        from stability import expm as expm_module

        unscaled = expm_module.THETA_TAYLOR
        try:
            expm_module.THETA_TAYLOR = 1e300
            bad = expm_soa(np.ascontiguousarray(A.transpose(1, 2, 0))).transpose(2, 0, 1)
        finally:
            expm_module.THETA_TAYLOR = unscaled
        assert not np.max(np.abs(bad - ref)) <= tol * np.max(np.abs(ref))


def test_interleaved_products_match_separate_products():
    from stability.magnus import ordered_product, ordered_product_soa

    rng = np.random.default_rng(5)
    A, B = rng.standard_normal((7, 3, 3)), rng.standard_normal((7, 3, 3))
    both = np.stack([A.transpose(1, 2, 0), B.transpose(1, 2, 0)], axis=3).reshape(3, 3, 14)
    got = ordered_product_soa(both, blocks=2)
    # reference: the plain sequential product E_7 ... E_1
    for k, X in enumerate((A, B)):
        ref = np.eye(3)
        for E in X:
            ref = E @ ref
        np.testing.assert_allclose(got[:, :, k], ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
        np.testing.assert_allclose(ordered_product(X), ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())


def test_chart_grid_guard(capsys):
    """``chart --grid 100000`` (1e10 evaluations) is refused with one line, exit 2."""
    assert cli_main(["chart", "--grid", "100000"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "grid points" in err


def test_first_resolved_beyond_the_step_limit_is_one_clear_error():
    """Entered with more steps than allowed (the adaptive engine's doubling can ask for that), the
    step search raises a FloquetError naming the limit, never an UnboundLocalError."""
    from stability.floquet import FloquetError, _first_resolved
    from stability.magnus import MAGNUS6

    def never(N):  # pragma: no cover - must not be called
        raise AssertionError("no solve above the limit")

    with pytest.raises(FloquetError, match="exceed the limit"):
        _first_resolved(never, 64, 32, MAGNUS6)
