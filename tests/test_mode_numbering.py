"""Mode labels of the generic path against Euler-Bernoulli theory.

The tuned mode set of a model file is its drive modes plus ``bending 1``
(:func:`linearize.analysis._dominant`), so the label must sit on the first
bending mode, not on the second.  Oracle: the pinned-hub Euler-Bernoulli
frequencies of the paper's link with tip mass (:func:`mbs_models.modes.analytic_frequencies`,
brentq on the boundary determinant; checked against an independent brentq in
``tests/test_exudyn_modes.py``).
"""
import math
import os
import re

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest

from linearize.analysis import frozen_modes
from linearize.constrained import linearize_orbit
from linearize.periodic_orbit import find_orbit
from mbs_models.modes import analytic_frequencies
from mbs_models.parameters import ManipulatorParameters
from mbs_models.console import exudyn_console

#: Relative tolerance on the frozen-time bending frequencies: the 4-element mesh error of the pinned-hub
#: frequencies (3.6e-4 and 4.0e-3 for f1, f2, docs/exudyn_notes.md) plus the stiffening of the frozen
#: state at t = 0 by rotation (hub rate pi Omega / 4 = 4.9 rad/s: (4.9 / (2 pi 78 Hz))^2 ~ 1e-4) and gravity
#: (a few 1e-3: the whole 78.0 vs 77.9 Hz); the neighbouring bending frequencies are 3.3x and 2.1x apart.
FREQUENCY_TOLERANCE = 1e-2


@pytest.fixture(scope="module")
def single_link_modes():
    with exudyn_console(True):
        orbit = find_orbit("single-link", 2 * math.pi, samples=16, verify=False, elements=4)
    return frozen_modes(linearize_orbit(orbit, 37.1617, 29.241), orbit)


def test_bending_labels_sit_on_the_euler_bernoulli_modes(single_link_modes):
    fm = single_link_modes
    freq = {lab: math.sqrt(abs(ev)) / (2 * math.pi) for lab, ev in zip(fm.labels, fm.eigenvalues)}
    eb = analytic_frequencies(ManipulatorParameters(), hub="pinned", count=2)
    for k, f_eb in enumerate(eb, start=1):
        assert f"bending {k}" in freq, f"no 'bending {k}' label: {fm.labels}"
        assert abs(freq[f"bending {k}"] / f_eb - 1.0) < FREQUENCY_TOLERANCE
    # the check can fail: bending 1 is not the second Euler-Bernoulli mode (3.3x apart)
    assert abs(freq["bending 1"] / eb[1] - 1.0) > 10 * FREQUENCY_TOLERANCE


def test_labels_of_each_kind_are_numbered_from_one_without_gaps(single_link_modes):
    fm = single_link_modes
    numbers: dict = {}
    for lab in fm.labels:
        m = re.fullmatch(r"(.+) (\d+)", lab)
        if m:
            numbers.setdefault(m.group(1), []).append(int(m.group(2)))
    assert {"bending", "axial"} <= set(numbers)
    for kind, ns in numbers.items():
        assert ns == list(range(1, len(ns) + 1)), f"{kind}: {ns}"
    # modes are in ascending frequency, so each kind's numbers follow the frequency order too
    assert np.all(np.diff(np.abs(fm.eigenvalues)) >= 0)
