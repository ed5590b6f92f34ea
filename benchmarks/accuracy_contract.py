"""Benchmark: the accuracy contract case by case -- actual error, estimate, cost.

For each case with an exact (or independently computed) answer this prints the default
``stability.floquet`` call's largest relative error of the multipliers ``>= 1e-6`` of the largest
(each against its nearest exact one; the moduli for the manipulator cases),
its own estimate of that error, whether the estimate covers it, the sub-intervals, the
evaluations of ``P`` and the CPU milliseconds (median of repeats, ``time.process_time``).  The
same script runs against any checkout (``PYTHONPATH=/path/to/checkout``): fields a checkout does
not have (``certified``, ``breakpoints``) are reported as ``n/a``, so a before/after pair of runs
compares the old and the new engine on the same cases.

Cases
-----
* ``meissner``: ``x'' + 0.05 x' + k(t) x = 0``, ``k`` = 0.55 on ``[0, T/3)``, -0.05 after,
  ``T = 2 pi`` (exact: ``expm(A2 2T/3) expm(A1 T/3)``), without and with the breakpoint declared,
  vectorised and as a plain callable;
* ``jordan``: a Lyapunov-transformed Jordan block (double defective multiplier ``e^(-0.05 T)``);
* ``mathieu-a1``: damped Mathieu on the transition curve ``a_1(q)`` (``scipy.special.mathieu_a``);
* ``reduced-T3-2pi``: the reduced manipulator at the paper's Table 3 gains, 2 pi (reference:
  ``magnus6`` at 4096 steps);
* ``rigid-two-link``: ``flexstab floquet --model tests/models/rigid_two_link.py`` at 2 pi against a
  scipy integration of the hand-derived linearisation (``--cli``; needs Exudyn, ~1 s).

Usage::

    python benchmarks/accuracy_contract.py [--cli] [--repeats 5]

Machine load changes the milliseconds, not the errors; compare runs made back to back.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from scipy.linalg import expm
from scipy.special import mathieu_a

from stability import floquet

T = 2.0 * math.pi
T1 = T / 3.0
A1 = np.array([[0.0, 1.0], [-0.55, -0.05]])
A2 = np.array([[0.0, 1.0], [0.05, -0.05]])


class Meissner:
    period = T

    def __call__(self, t):
        return self.evaluate(np.array([t]))[0]

    def evaluate(self, times):
        t = np.mod(np.asarray(times, float), T)
        return np.where((t < T1)[:, None, None], A1, A2)


class MeissnerBreak(Meissner):
    breakpoints = (T1,)


def meissner_plain(t):
    return A1 if (t % T) < T1 else A2


def jordan():
    J = np.array([[-0.05, 1.0], [0.0, -0.05]])

    def P(t):
        L = np.array([[1.0 + 0.3 * np.sin(t), 0.2 * np.cos(t)], [0.1 * np.sin(2 * t), 1.0]])
        dL = np.array([[0.3 * np.cos(t), -0.2 * np.sin(t)], [0.2 * np.cos(2 * t), 0.0]])
        Li = np.linalg.inv(L)
        return dL @ Li + L @ J @ Li

    return P, np.array([math.exp(-0.05 * T)] * 2)


def mathieu_a1(q=1.0, c=0.1):
    a = float(mathieu_a(1, q)) + 0.25 * c * c

    def P(t):
        return np.array([[0.0, 1.0], [-(a - 2.0 * q * math.cos(2.0 * t)), -c]])

    return P, np.array([-math.exp(-0.5 * c * math.pi)] * 2)


def _case(name, call, exact, moduli_only=False):
    """Errors of the multipliers (each against its nearest exact one), or of the sorted moduli."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = call()
    ex = np.asarray(exact, complex)
    got = np.asarray(res.multipliers, complex)
    keep = np.abs(got) >= 1e-6 * np.abs(got).max()
    if moduli_only:
        mod = np.sort(np.abs(got))[::-1]
        exm = np.sort(np.abs(ex))[::-1]
        err = float(np.max(np.abs(mod[keep] / exm[keep] - 1.0)))
    else:
        err = float(max(np.min(np.abs(z - ex)) / abs(z) for z in got[keep]))
    digits = np.asarray(res.reliable_digits)
    est = float(np.max(10.0 ** -digits[keep]))
    certified = getattr(res, "certified", None)
    return {"case": name, "error": err, "estimate": est, "covers": bool(est >= err), "n_steps": int(res.n_steps),
            "evaluations": int(res.n_evaluations),
            "certified": None if certified is None or len(certified) == 0 else bool(np.all(certified[keep]))}


def _timed(call, repeats):
    times = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        call()
        for _ in range(repeats):
            t = time.process_time()
            call()
            times.append(time.process_time() - t)
    return 1e3 * statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cli", action="store_true", help="also the rigid two-link model file through the CLI")
    args = ap.parse_args(argv)
    exact_meissner = np.linalg.eigvals(expm(A2 * (T - T1)) @ expm(A1 * T1))
    Pj, exj = jordan()
    Pm, exm = mathieu_a1()
    from mbs_models.reduced import ReducedModel

    red = ReducedModel(2 * math.pi, 37.1617, 29.2410)
    ex_red = floquet(red, n_steps=4096, error_estimate=False).multipliers
    cases = [
        ("meissner", lambda: floquet(Meissner()), exact_meissner),
        ("meissner plain callable", lambda: floquet(meissner_plain, period=T), exact_meissner),
        ("meissner + breakpoint", lambda: floquet(MeissnerBreak()), exact_meissner),
        ("jordan", lambda: floquet(Pj, period=T), exj),
        ("mathieu-a1", lambda: floquet(Pm, period=math.pi), exm),
        ("reduced-T3-2pi", lambda: floquet(red), ex_red),
    ]
    rows = []
    for name, call, exact in cases:
        row = _case(name, call, exact, moduli_only=name.startswith("reduced"))
        row["cpu_ms"] = _timed(call, args.repeats)
        rows.append(row)
    if args.cli:
        sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
        from test_accuracy_contract import _two_link_oracle

        from flexstab.cli import main as cli
        import contextlib
        import io

        exact = np.abs(_two_link_oracle(2 * math.pi))
        model = str(Path(__file__).resolve().parent.parent / "tests" / "models" / "rigid_two_link.py")
        buf = io.StringIO()
        t = time.process_time()
        with contextlib.redirect_stdout(buf), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cli(["floquet", "--model", model, "--omega", "2pi", "--json"])
        cpu = 1e3 * (time.process_time() - t)
        d = json.loads(buf.getvalue())
        mod = np.sort(np.asarray(d["moduli"]))[::-1]
        err = float(np.max(np.abs(mod / np.sort(exact)[::-1] - 1.0)))
        est = float(np.max(10.0 ** -np.asarray(d["reliable_digits"])))
        rows.append({"case": "rigid-two-link CLI", "error": err, "estimate": est, "covers": est >= err,
                     "n_steps": d["n_steps"], "evaluations": d["n_evaluations"],
                     "certified": d.get("all_certified"), "cpu_ms": cpu})
    print(f"{'case':26s} {'error':>9s} {'estimate':>9s} covers {'N':>6s} {'evals':>7s} certified {'CPU ms':>8s}")
    for r in rows:
        cert = "n/a" if r["certified"] is None else str(r["certified"])
        print(f"{r['case']:26s} {r['error']:9.1e} {r['estimate']:9.1e} {str(r['covers']):6s} {r['n_steps']:6d} "
              f"{r['evaluations']:7d} {cert:9s} {r['cpu_ms']:8.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
