"""Frozen-modal bases whose holonomy is a Jordan block (no eigenvector basis), e.g. the free spin of
a hanging 3D pendulum with a ``NodeRigidBodyRxyz`` node.

Oracles: for samples ``V_k = expm(L k / K)`` of an exactly known basis the periodic basis is the
identity; the 3D pendulum's swing modes obey the Mathieu equation
``J_p th'' + m l (g - a omega^2 cos(omega t)) th = 0`` (monodromy by scipy's DOP853 at rtol 1e-12),
its spin about the vertical is free (double multiplier 1).
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from stability.modal import ModalBasisError, _remove_holonomy

MODELS = Path(__file__).with_name("models")


@pytest.mark.parametrize("H", [
    [[1.0, 0.5], [0.0, 1.0]],                                       # 2x2 Jordan block
    [[1.0, 1.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]],            # 3x3 Jordan block
    [[math.e, 1.0], [0.0, math.e]],                                 # Jordan block at e
])
def test_jordan_holonomy_gives_the_exact_periodic_basis(H):
    """``V_k = expm(L k/K)`` with ``expm(L) = H`` defective: removing the holonomy leaves exactly the
    identity at every sample (the smooth periodic part).  A wrong answer -- the samples unchanged, or
    the garbage ``S^-1`` of a defective eigen-decomposition -- is far from it."""
    H = np.array(H)
    n, K = H.shape[0], 8
    L = np.real(scipy.linalg.logm(H))
    V = np.stack([scipy.linalg.expm(L * k / K) for k in range(K + 1)])
    raw = V[:K].copy()
    out = _remove_holonomy(V, {n: np.arange(n)[None, :]}, np.arange(K) / K)
    assert np.all(np.isfinite(out))
    assert np.max(np.abs(out - np.eye(n))) <= 1e-12
    assert np.max(np.abs(raw - np.eye(n))) > 0.1  # the check can fail: the input is not periodic


def test_reversing_holonomy_is_a_modal_basis_error_not_a_linalg_error():
    """A real eigenvector that reverses (holonomy -1) has no real logarithm: ``ModalBasisError``
    (the fallback's signal), never numpy's ``LinAlgError`` (which the CLI would misreport)."""
    V = np.stack([np.eye(1), np.eye(1), -np.eye(1)])
    with pytest.raises(ModalBasisError):
        _remove_holonomy(V, {1: np.arange(1)[None, :]}, np.arange(2) / 2)


def _mathieu_multipliers(omega: float) -> np.ndarray:
    spec = __import__("importlib.util").util.spec_from_file_location("sp_rxyz", MODELS / "spherical_pendulum_rxyz.py")
    mod = __import__("importlib.util").util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    m, l, g, a = mod.MASS, mod.LENGTH, mod.GRAVITY, mod.AMPLITUDE
    Jp = mod.INERTIA[0] + m * l * l

    def f(t, y):
        X = y.reshape(2, 2)
        A = np.array([[0.0, 1.0], [-m * l * (g - a * omega**2 * math.cos(omega * t)) / Jp, 0.0]])
        return (A @ X).ravel()

    sol = scipy.integrate.solve_ivp(f, (0, 2 * math.pi / omega), np.eye(2).ravel(), method="DOP853",
                                    rtol=1e-12, atol=1e-14)
    return np.linalg.eigvals(sol.y[:, -1].reshape(2, 2))


def test_rxyz_spherical_pendulum_at_omega_12_keeps_the_modal_frame_and_matches_mathieu():
    """The hanging Rxyz spherical pendulum at omega = 12 (where the free spin's Jordan holonomy made
    the frozen-modal basis fail): the modal frame is kept, the four swing multipliers are the
    Mathieu equation's (each twice), the spin's two are 1 (a Jordan pair: ~sqrt(eps)-sensitive)."""
    from linearize.analysis import analyze

    omega = 12.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no fallback warning
        res = analyze(str(MODELS / "spherical_pendulum_rxyz.py"), omega, n_steps=None, verify_orbit=False)
    assert res.frame == "modal"
    mus = list(np.asarray(res.floquet.multipliers, dtype=complex))
    expected = list(_mathieu_multipliers(omega)) * 2
    for e in expected:
        j = int(np.argmin([abs(e - x) for x in mus]))
        assert abs(e - mus.pop(j)) <= 1e-7
    assert len(mus) == 2 and all(abs(x - 1.0) <= 1e-5 for x in mus)
    # a wrong answer is rejected: the Mathieu multipliers at another omega are not these
    wrong = _mathieu_multipliers(11.5)
    assert min(abs(wrong[0] - x) for x in res.floquet.multipliers) > 1e-3


def test_a_singular_matrix_inside_a_computation_is_exit_1_not_bad_input(monkeypatch, capsys):
    """numpy's ``LinAlgError`` is a ``ValueError``; the CLI reports it as a numerical failure (exit 1),
    never as bad input (exit 2)."""
    import linearize.analysis
    from flexstab.cli import main

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr(linearize.analysis, "analyze", singular)
    rc = main(["floquet", "--model", str(MODELS / "spherical_pendulum_rxyz.py"), "--omega", "12"])
    err = capsys.readouterr().err
    assert rc == 1 and "failed: LinAlgError: Singular matrix" in err
    # bad input still exits 2
    assert main(["floquet", "--model", str(MODELS / "no_such_model.py")]) == 2
