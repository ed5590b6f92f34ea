"""Drawing of ANCF arms (flexstab.arm_figures): centre lines against rigid forward kinematics."""
from __future__ import annotations

import math
import os
import types

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import pytest

exu = pytest.importorskip("exudyn")

from flexstab.arm_figures import arm_layout, beam_centerlines, plot_poses  # noqa: E402
from mbs_models.builtin.two_link import TwoLinkParameters, build  # noqa: E402
from mbs_models.model_file import builtin_model  # noqa: E402
from test_two_link_model import _rigid_pose  # noqa: E402

P = TwoLinkParameters()


def _mbs():
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    build(mbs, 2 * math.pi, elements=2)
    mbs.Assemble()
    return sc, mbs


def test_centerlines_follow_rigid_kinematics():
    sc, mbs = _mbs()
    q1, q2 = 0.3, 0.7
    q, _, _ = _rigid_pose(mbs, q1, q2)
    lines = beam_centerlines(arm_layout(mbs), q, points=11)
    assert len(lines) == 4  # 2 elements per link
    elbow = P.length1 * np.array([math.cos(q1), math.sin(q1)])
    tip = elbow + P.length2 * np.array([math.cos(q1 + q2), math.sin(q1 + q2)])
    np.testing.assert_allclose(lines[0][0], [0, 0], atol=1e-14)
    np.testing.assert_allclose(lines[1][-1], elbow, atol=1e-14)
    np.testing.assert_allclose(lines[-1][-1], tip, atol=1e-14)
    # cubic Hermite with consistent slopes reproduces the straight segment exactly
    for line, angle in zip(lines, (q1, q1, q1 + q2, q1 + q2)):
        d = np.diff(line, axis=0)
        np.testing.assert_allclose(np.arctan2(d[:, 1], d[:, 0]), angle, atol=1e-12)
    # a wrong reading (elbow angle as absolute) would put the tip elsewhere
    wrong = elbow + P.length2 * np.array([math.cos(q2), math.sin(q2)])
    assert np.linalg.norm(lines[-1][-1] - wrong) > 0.1


def test_plot_poses_writes_png(tmp_path):
    sc, mbs = _mbs()
    omega = 2 * math.pi

    def state(t):
        q1 = math.pi / 2 + math.pi / 4 * math.sin(omega * t)
        q2 = math.pi / 4 * math.sin(omega * t)
        return _rigid_pose(mbs, q1, q2)[0], None, None

    orbit = types.SimpleNamespace(model=builtin_model("two-link", elements=2), omega=omega, period=1.0, state=state)
    path = plot_poses(orbit, tmp_path / "poses.png", snapshots=6)
    assert path.exists() and path.stat().st_size > 10_000
