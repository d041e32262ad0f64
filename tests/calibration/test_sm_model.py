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
