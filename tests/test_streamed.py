"""streamed_floquet (chunked Magnus product) against floquet() and an exact answer."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stability import floquet
from stability.streamed import streamed_floquet


def _mathieu(a=1.3, q=0.4):
    def P(t):
        return np.array([[0.0, 1.0], [-(a - 2 * q * math.cos(2 * t)), -0.05]])
    P.period = math.pi
    return P


def test_same_product_as_floquet_whatever_the_chunk():
    P = _mathieu()
    ref = floquet(P, method="magnus2", n_steps=300, error_estimate=False)
    for chunk in (7, 64, 1000):
        r = streamed_floquet(P, math.pi, 300, chunk=chunk)
        assert np.allclose(np.sort_complex(r.multipliers), np.sort_complex(ref.multipliers), rtol=1e-12, atol=1e-14)


def test_liouville_and_rejects_wrong_steps():
    """det Phi = exp(-0.05 pi) exactly (trace of P is constant); a coarse product is visibly different."""
    P = _mathieu()
    r = streamed_floquet(P, math.pi, 4096, chunk=500)
    assert abs(np.prod(r.multipliers).real - math.exp(-0.05 * math.pi)) < 1e-12
    fine = streamed_floquet(P, math.pi, 8192)
    coarse = streamed_floquet(P, math.pi, 8)
    assert np.max(np.abs(np.sort_complex(fine.multipliers) - np.sort_complex(r.multipliers))) < 1e-6
    assert np.max(np.abs(np.sort_complex(fine.multipliers) - np.sort_complex(coarse.multipliers))) > 1e-4


def test_bad_arguments():
    with pytest.raises(ValueError, match="method"):
        streamed_floquet(_mathieu(), math.pi, 10, method="rk4")
    with pytest.raises(ValueError, match="n_steps"):
        streamed_floquet(_mathieu(), math.pi, 0)
