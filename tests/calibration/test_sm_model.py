"""AGEBOT serial arm: FK/IK and the Jacobian of every SM method against finite differences."""
import math

import numpy as np
import pytest

from calibration.errors import UnreachablePose
from calibration.robots import get_robot
from tests.calibration.helpers import assert_columns_close, dataset, fd_jacobian

SM = get_robot("agebot-sm")


def test_base_offset_matches_brief():
    np.testing.assert_allclose(SM.base_offset(SM.true)[:2], [0.2, 0.4], atol=1e-4)


@pytest.mark.parametrize("elbow", [1, -1])
def test_ik_fk_roundtrip(elbow):
    rng = np.random.default_rng(elbow + 2)
    off = np.r_[SM.base_offset(SM.true), 0]
    n = 0
    while n < 20:
        X = off + rng.uniform([0.9, 0.2, -0.7, -0.35], [1.5, 1.0, 0.7, 0.35])
        try:
            qm = SM.ik(X, SM.true, elbow=elbow)
        except UnreachablePose:
            continue
        n += 1
        np.testing.assert_allclose(SM.fk(qm, SM.true)[0], X, atol=1e-12)
        assert SM.elbow_of(qm, SM.true) == elbow


def test_unreachable_pose_is_reported_not_returned():
    with pytest.raises(UnreachablePose, match="out of the arm's reach"):
        SM.ik([5.0, 5.0, 0.0, 0.0], SM.true)


def test_phi_is_the_last_link_angle():
    qm = SM.ik([1.3, 1.2, 0.1, math.radians(10)], SM.true)
    q = SM.chain.joints(qm, SM.true)[0]
    assert SM.fk(qm, SM.true)[0, 3] == pytest.approx(math.pi / 2 + q[1:].sum())


def test_fk_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    qm = rng.uniform(-150, 150, (6, 4))
    _, psi = SM.fk_jacobian(qm, SM.true)
    num = fd_jacobian(lambda x: SM.fk(qm, x).reshape(-1), SM.true)
    assert_columns_close(psi.reshape(-1, 13), num, names=SM.param_names)


@pytest.mark.parametrize("method,residual,zero", [
    ("sm-full-pose", "plain", "exact"), ("sm-distance", "plain", "exact"),
    ("sm-distance", "squared", "exact"), ("sm-self-redundancy", "plain", "exact"),
    ("sm-plane", "plain", "exact"), ("sm-distance-tilt", "plain", "exact"),
    ("sm-distance-tilt", "squared", "exact"),
    # the draw-wire zero as a reading: distance_off is one more column
    ("sm-distance", "plain", "reading"), ("sm-distance", "squared", "reading"),
    ("sm-distance-tilt", "plain", "reading"), ("sm-distance-tilt", "squared", "reading")])
def test_method_observation_matrix_matches_finite_differences(method, residual, zero):
    model, _ = dataset(method, seed=1, distance_zero=zero, distance_off=2e-5)
    if zero == "reading":
        assert model.names[-1] == "distance_off"
        model.x0[-1] = 3e-3     # away from 0, where its column would be trivial
    if residual == "squared":
        model.residual = "squared"
    x = model.x0 + 0.01 * np.random.default_rng(2).normal(size=model.n_params) * np.abs(model.x0)
    _, W = model.evaluate(x)
    # W = d predicted / dx = -d residual / dx
    num = fd_jacobian(lambda v: -model.evaluate(v)[0], x)
    assert_columns_close(W, num, names=model.names)


def test_canonical_parameters_are_the_same_robot():
    """Angles wrapped to (-pi, pi] and (theta0 + pi, -a0) turned back to a0 >= 0:
    the same FK, and the covariance's a0 row and column change sign."""
    x = SM.true.copy()
    x[SM.index("q2_off")] += 4 * math.pi
    x[SM.index("q3_off")] = -math.pi            # -> +pi (the half-open range)
    x[SM.index("theta0")] += math.pi
    x[SM.index("a0")] *= -1
    xc, s = SM.canonical(x)
    qm = np.random.default_rng(3).uniform(-100, 100, (5, 4))
    a, b = SM.fk(qm, xc), SM.fk(qm, x)
    np.testing.assert_allclose(a[:, :3], b[:, :3], atol=1e-12)
    np.testing.assert_allclose(np.cos(a[:, 3] - b[:, 3]), 1.0, atol=1e-12)   # phi mod 2 pi
    assert xc[SM.index("a0")] > 0 and xc[SM.index("q3_off")] == pytest.approx(math.pi)
    assert np.all((xc[[1, 2, 3, 11]] > -math.pi) & (xc[[1, 2, 3, 11]] <= math.pi))
    np.testing.assert_allclose(xc[SM.index("theta0")], SM.true[SM.index("theta0")], atol=1e-12)
    assert s[SM.index("a0")] == -1 and np.sum(s == 1) == 12


def test_negative_lengths_are_the_same_robot_turned_around():
    """(L2, q2_off, q3_off) ~ (-L2, q2_off + pi, q3_off + pi), likewise L3: the same FK.
    (L4, q4_off, q2_off, theta0) ~ (-L4, ... + pi): the same distances to the origin and
    phi modulo 2 pi (the distance methods' frame_free form)."""
    qm = np.random.default_rng(4).uniform(-100, 100, (6, 4))
    for length, angles, frame_free in (("L2", ("q2_off", "q3_off"), False),
                                       ("L3", ("q3_off", "q4_off"), False),
                                       ("L4", ("q4_off", "q2_off", "theta0"), True)):
        x = SM.true.copy()
        x[SM.index(length)] *= -1
        for a in angles:
            x[SM.index(a)] += math.pi
        xc, s = SM.canonical(x, frame_free=frame_free)
        np.testing.assert_allclose(xc, SM.canonical(SM.true)[0], atol=1e-12)
        assert s[SM.index(length)] == -1
        a, b = SM.fk(qm, x), SM.fk(qm, SM.true)
        np.testing.assert_allclose(np.linalg.norm(a[:, :3], axis=1),
                                   np.linalg.norm(b[:, :3], axis=1), atol=1e-12)
        np.testing.assert_allclose(np.cos(a[:, 3] - b[:, 3]), 1.0, atol=1e-12)
        if not frame_free:
            np.testing.assert_allclose(a[:, :3], b[:, :3], atol=1e-12)
