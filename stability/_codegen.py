"""Generator of the unrolled compiled Magnus kernels (:mod:`stability._kernel4`).

Writes the fused loop of :func:`stability._compiled._magnus_solve_py` for one
fixed matrix size with every ``n x n`` matrix held in scalar locals and every
product written out, so that the compiler keeps the matrices in registers (for
4x4 about 5x faster than the loops over a run-time ``n``).  The arithmetic is
the same, term by term.  Run ``python -m stability._codegen 4`` to regenerate
``stability/_kernel4.py`` (committed, so that numba can cache its machine code).
"""
from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["generate"]


def _m(name: str, n: int) -> list[list[str]]:
    return [[f"{name}{i}{j}" for j in range(n)] for i in range(n)]


def _mul(out: list[str], C, A, B, n: int, ind: str, scale: str = "", add=None) -> None:
    """``C = scale * (A @ B) [+ add_ij]`` (``add`` a function of i, j returning a string or None)."""
    for i in range(n):
        for j in range(n):
            expr = " + ".join(f"{A[i][k]} * {B[k][j]}" for k in range(n))
            expr = f"({expr})" if scale or add else expr
            if scale:
                expr = f"{scale} * {expr}"
            extra = add(i, j) if add else None
            if extra:
                expr = f"{expr} + {extra}"
            out.append(f"{ind}{C[i][j]} = {expr}")


def _comm(out: list[str], C, A, B, n: int, ind: str, scale: str = "") -> None:
    """``C = scale * (A B - B A)``."""
    for i in range(n):
        for j in range(n):
            ab = " + ".join(f"{A[i][k]} * {B[k][j]}" for k in range(n))
            ba = " + ".join(f"{B[i][k]} * {A[k][j]}" for k in range(n))
            expr = f"({ab}) - ({ba})"
            out.append(f"{ind}{C[i][j]} = {scale} * ({expr})" if scale else f"{ind}{C[i][j]} = {expr}")


def _norm1(out: list[str], target: str, M, n: int, ind: str, update: bool) -> None:
    """``target = max(target, ||M||_1)`` (NaN-propagating) or ``target = ||M||_1``."""
    cols = [" + ".join(f"abs({M[i][j]})" for i in range(n)) for j in range(n)]
    out.append(f"{ind}_nrm = {cols[0]}")
    for c in cols[1:]:
        out.append(f"{ind}_c = {c}")
        out.append(f"{ind}if not _c <= _nrm:")
        out.append(f"{ind}    _nrm = _c")
    if update:
        out.append(f"{ind}if not _nrm <= {target}:")
        out.append(f"{ind}    {target} = _nrm")
    else:
        out.append(f"{ind}{target} = _nrm")


def generate(n: int) -> str:
    """Source of ``magnus_solve_{n}(P, h, order, phi, stats)`` (same contract as ``_magnus_solve_py``)."""
    L: list[str] = []
    a1, a2, a3, c1, t1, t2, om = (_m(x, n) for x in ("a1_", "a2_", "a3_", "c1_", "t1_", "t2_", "om"))
    A2, A3, A4, X, Y, ph, q0, q1, q2 = (_m(x, n) for x in ("B2_", "B3_", "B4_", "X", "Y", "ph", "p0_", "p1_", "p2_"))
    I4 = " " * 4
    L.append(f"def magnus_solve_{n}(P, h, order, phi, stats):")
    L.append(f"{I4}N = P.shape[0]")
    L.append(f"{I4}c = _TAYLOR")
    for i in range(n):
        for j in range(n):
            L.append(f"{I4}{ph[i][j]} = {1.0 if i == j else 0.0}")
    L.append(f"{I4}logdet = 0.0")
    L.append(f"{I4}corr_max = 0.0")
    L.append(f"{I4}om_max = 0.0")
    L.append(f"{I4}for k in range(N):")
    I8, I12 = " " * 8, " " * 12
    L.append(f"{I8}if order == 6:")
    for i in range(n):
        for j in range(n):
            for q, name in enumerate((q0, q1, q2)):
                L.append(f"{I12}{name[i][j]} = P[k, {q}, {i}, {j}]")
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{a1[i][j]} = h * {q1[i][j]}")
            L.append(f"{I12}{a2[i][j]} = _S15_3 * h * ({q2[i][j]} - {q0[i][j]})")
            L.append(f"{I12}{a3[i][j]} = _TEN_3 * h * ({q2[i][j]} - 2.0 * {q1[i][j]} + {q0[i][j]})")
    _comm(L, c1, a1, a2, n, I12)
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{t1[i][j]} = 2.0 * {a3[i][j]} + {c1[i][j]}")
    _comm(L, t2, a1, t1, n, I12, scale="(-1.0 / 60.0)")
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{t1[i][j]} = -20.0 * {a1[i][j]} - {a3[i][j]} + {c1[i][j]}")
            L.append(f"{I12}{t2[i][j]} = {a2[i][j]} + {t2[i][j]}")
    _comm(L, om, t1, t2, n, I12, scale="(1.0 / 240.0)")
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{om[i][j]} = {a1[i][j]} + {a3[i][j]} / 12.0 + {om[i][j]}")
    # commutator part: om - h (5 p0 + 8 p1 + 5 p2) / 18
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{t1[i][j]} = {om[i][j]} - h * ((5.0 * {q0[i][j]} + 8.0 * {q1[i][j]} + 5.0 * {q2[i][j]}) / 18.0)")
    _norm1(L, "corr_max", t1, n, I12, update=True)
    L.append(f"{I8}else:")
    for i in range(n):
        for j in range(n):
            for q, name in enumerate((q0, q1)):
                L.append(f"{I12}{name[i][j]} = P[k, {q}, {i}, {j}]")
    _comm(L, t2, q1, q0, n, I12)
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{om[i][j]} = 0.5 * h * ({q0[i][j]} + {q1[i][j]}) + _S3_12 * h * h * {t2[i][j]}")
            L.append(f"{I12}{t1[i][j]} = {om[i][j]} - 0.5 * h * ({q0[i][j]} + {q1[i][j]})")
    _norm1(L, "corr_max", t1, n, I12, update=True)
    L.append(f"{I8}logdet += " + " + ".join(om[i][i] for i in range(n)))
    _norm1(L, "om_max", om, n, I8, update=True)
    # exponential: degree-16 Taylor, Paterson-Stockmeyer, scaling and squaring
    _mul(L, A2, om, om, n, I8)
    _mul(L, A3, A2, om, n, I8)
    _mul(L, A4, A2, A2, n, I8)
    _norm1(L, "n3", A3, n, I8, update=False)
    _norm1(L, "n4", A4, n, I8, update=False)
    L.append(f"{I8}alpha = max(n3 ** (1.0 / 3.0), n4 ** 0.25)")
    L.append(f"{I8}if not math.isfinite(alpha):")
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}phi[{i}, {j}] = math.nan")
    L.append(f"{I12}stats[0] = logdet")
    L.append(f"{I12}stats[1] = math.inf")
    L.append(f"{I12}stats[2] = math.inf")
    L.append(f"{I12}return")
    L.append(f"{I8}sq = 0")
    L.append(f"{I8}if alpha > _THETA:")
    L.append(f"{I12}sq = int(math.ceil(math.log2(alpha / _THETA)))")
    L.append(f"{I8}if sq > 0:")
    L.append(f"{I12}f = 2.0 ** (-sq)")
    L.append(f"{I12}f2 = f * f")
    L.append(f"{I12}f3 = f2 * f")
    L.append(f"{I12}f4 = f2 * f2")
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{om[i][j]} *= f")
            L.append(f"{I12}{A2[i][j]} *= f2")
            L.append(f"{I12}{A3[i][j]} *= f3")
            L.append(f"{I12}{A4[i][j]} *= f4")
    for i in range(n):
        for j in range(n):
            d = " + c[12]" if i == j else ""
            L.append(f"{I8}{X[i][j]} = c[16] * {A4[i][j]} + c[13] * {om[i][j]} + c[14] * {A2[i][j]} "
                     f"+ c[15] * {A3[i][j]}{d}")
    for blk in (2, 1, 0):
        def add(i, j, blk=blk):
            d = f" + c[{4 * blk}]" if i == j else ""
            return (f"c[{4 * blk + 1}] * {om[i][j]} + c[{4 * blk + 2}] * {A2[i][j]} "
                    f"+ c[{4 * blk + 3}] * {A3[i][j]}{d}")
        _mul(L, Y, A4, X, n, I8, add=add)
        src, dst = Y, X
        for i in range(n):
            for j in range(n):
                L.append(f"{I8}{dst[i][j]} = {src[i][j]}")
    L.append(f"{I8}for _s in range(sq):")
    _mul(L, Y, X, X, n, I12)
    for i in range(n):
        for j in range(n):
            L.append(f"{I12}{X[i][j]} = {Y[i][j]}")
    # phi <- E_k phi
    _mul(L, Y, X, ph, n, I8)
    for i in range(n):
        for j in range(n):
            L.append(f"{I8}{ph[i][j]} = {Y[i][j]}")
    for i in range(n):
        for j in range(n):
            L.append(f"{I4}phi[{i}, {j}] = {ph[i][j]}")
    L.append(f"{I4}stats[0] = logdet")
    L.append(f"{I4}stats[1] = corr_max")
    L.append(f"{I4}stats[2] = om_max")
    header = [
        f'"""Unrolled Magnus-4/6 kernel for {n}x{n} systems.  GENERATED by ``python -m stability._codegen {n}``:',
        'do not edit (see :mod:`stability._codegen` and :func:`stability._compiled._magnus_solve_py`)."""',
        "# flake8: noqa",
        "import math",
        "",
        "import numpy as np",
        "",
        "_TAYLOR = np.array([1.0 / math.factorial(k) for k in range(17)])",
        "_THETA = 0.82",
        "_S15_3 = math.sqrt(15.0) / 3.0",
        "_TEN_3 = 10.0 / 3.0",
        "_S3_12 = math.sqrt(3.0) / 12.0",
        "",
        "",
    ]
    return "\n".join(header + L) + "\n"


if __name__ == "__main__":  # pragma: no cover
    size = int(sys.argv[1]) if len(sys.argv) > 1 else 4
    path = Path(__file__).with_name(f"_kernel{size}.py")
    path.write_text(generate(size))
    print(f"wrote {path}")
