"""PM calibration (report sections 9-10): generalized Jacobians, the pm-ik,
pm-fk and pm-tilt methods on the one solver, the robust start from the report's
nominal values, and the compensation of q3_off, k3 (eqs. 112-113).

Ground truth: the report's true PM; poses sampled in the report's +-20 deg box.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.identifiability import INFLUENCES, IDENTIFIABLE
from calibration.methods import MethodData, build
from calibration.methods.pm_common import COMPENSATION_NOTE, compensation_note, parse_components
from calibration.methods.pm_fk import ForwardKinematics
from calibration.methods.pm_ik import InverseKinematics
from calibration.methods.pm_tilt import (HEADING_NOTE, Tilt, heading_grid, heading_uncertainty,
                                         ik_modulo_heading)
from calibration.planning import PM_BOX, box_array, sample_poses
from calibration.pm_start import robust_start
from calibration.robots.agebot_pm import (NOMINAL, TRUE, AgebotPM, euler_xyz, gravity_tilt,
                                          rot_xyz, tilt_jacobian)
from calibration.solver import solve
from tests.calibration.helpers import assert_columns_close

ROBOT = AgebotPM()
ABG = ("alpha", "beta", "gamma")
MOUNT = np.array([0.02, -0.015])
DEG20 = math.radians(20)
# the +-20 deg workspace, 9^3 orientations
GRID = np.array(np.meshgrid(*[np.linspace(-DEG20, DEG20, 9)] * 3)).reshape(3, -1).T


def poses(m, seed):
    plan = sample_poses(ROBOT, TRUE, box_array(ROBOT, PM_BOX), m, np.random.default_rng(seed))
    return plan.targets, plan.qm


def orientation_data(m, seed, comps=ABG, noise=0.0):
    X, qm = poses(m, seed)
    X = X + noise * np.random.default_rng(seed + 1000).normal(size=X.shape)
    idx = [ABG.index(c) for c in comps]
    return MethodData(qm, {"orientation": X[:, idx]}, components=comps)


def tilt_data(m, seed, mount=MOUNT):
    X, qm = poses(m, seed)
    return MethodData(qm, {"tilt": np.column_stack(gravity_tilt(rot_xyz(X), mount))})


def equivalent_truth(q3_off, k3):
    """The member of the true robot's equivalence family (eqs. 112-113) with the
    given q3_off, k3: lengths, offsets, gear ratios times s, then v and the
    offsets shifted together."""
    s = k3 / TRUE[9]
    e = TRUE * s
    shift = q3_off - s * TRUE[6]
    e[3] += shift
    e[4:7] += shift
    return e


def fd(f, x, steps):
    cols = []
    for j, h in enumerate(steps):
        e = np.zeros_like(x)
        e[j] = h
        cols.append((f(x + e) - f(x - e)) / (2 * h))
    return np.stack(cols, axis=-1)


# -- generalized Jacobians (report eqs. 106, 123) -------------------------------------------
def test_chain_jacobian_first_row_of_inverse_is_rod_direction_over_uz():
    X, _ = poses(6, 1)
    _, J, u = ROBOT.chain_jacobians(X, TRUE)
    np.testing.assert_allclose(np.linalg.inv(J)[..., 0, :], u / u[..., 2:3], atol=1e-12)


@pytest.mark.parametrize("xi", [TRUE, equivalent_truth(0.05, 1 / 8000)])
def test_psi_iku_matches_finite_differences_of_the_ik(xi):
    X, _ = poses(8, 2)
    qm = ROBOT.ik_actuators(X, TRUE)  # any actuator values: the k columns are -qm

    def closure(x):  # Fbar^-1(X, a1, a2, l, v) - (K Qm + Q_off), joint space (eq. 106)
        q, _ = ROBOT.ik_joints(X, x)
        return q - ROBOT.joints(qm, x)

    P = ROBOT.psi_iku(X, xi, qm)
    assert P.shape == (8, 3, 10)
    assert_columns_close(P, fd(closure, xi, 1e-6 * np.abs(xi)), names=ROBOT.param_names)


def test_psi_pku_matches_finite_differences_of_the_fk():
    X, qm = poses(8, 3)
    P = ROBOT.psi_pku(X, TRUE, qm)
    num = fd(lambda x: ROBOT.fk(qm, x, guess=X), TRUE, 1e-6 * np.abs(TRUE))
    assert_columns_close(P, num, names=ROBOT.param_names)


# -- the physical inclinometer ----------------------------------------------------------------
def test_gravity_tilt_conventions():
    a, b, c = 0.2, -0.15, 0.3
    assert np.allclose(gravity_tilt(rot_xyz([a, 0, 0])[0]), (a, 0))
    assert np.allclose(gravity_tilt(rot_xyz([0, b, 0])[0]), (0, b))
    Rz = rot_xyz([0, 0, c])[0]
    Ry, Rx = rot_xyz([0, b, 0])[0], rot_xyz([a, 0, 0])[0]
    # yaw about the vertical (Rz on the left) is not seen; yaw about the sensor's
    # own z axis (Rz on the right) is, since it turns the sensor axes
    assert np.allclose(gravity_tilt(Rz @ Ry @ Rx), (a, b))
    assert not np.allclose(gravity_tilt(Ry @ Rx @ Rz), (a, b))
    assert np.allclose(gravity_tilt(rot_xyz([0, 0, 0])[0], mount=(a, b)), (a, b), atol=0.05)


def test_gravity_tilt_is_the_simulators():
    import drivers.sim.robot as sim
    X, _ = poses(10, 4)
    R = rot_xyz(X)
    np.testing.assert_array_equal(np.array(gravity_tilt(R, MOUNT)),
                                  np.array(sim.gravity_tilt(R, MOUNT)))
    assert sim.gravity_tilt(R[0], MOUNT) == gravity_tilt(R[0], MOUNT)


def test_tilt_jacobian_matches_finite_differences():
    X, _ = poses(6, 5)
    t, dX, dm = tilt_jacobian(X, MOUNT)
    np.testing.assert_allclose(t, np.column_stack(gravity_tilt(rot_xyz(X), MOUNT)), atol=1e-15)
    h = 1e-6
    num = np.stack([(tilt_jacobian(X + h * e, MOUNT)[0] - tilt_jacobian(X - h * e, MOUNT)[0])
                    / (2 * h) for e in np.eye(3)], axis=-1)
    assert_columns_close(dX, num)
    assert_columns_close(dm, fd(lambda m: tilt_jacobian(X, m)[0], MOUNT, [1e-6] * 2))


# -- the methods' observation matrices ----------------------------------------------------
@pytest.mark.parametrize("name, data", [
    ("pm-ik", orientation_data(6, 6)),
    ("pm-fk", orientation_data(6, 6, ("alpha", "beta"))),
    ("pm-tilt", tilt_data(6, 6)),
])
def test_observation_matrix_is_minus_residual_derivative(name, data):
    x = np.r_[equivalent_truth(0.01, 1 / 9500), [0.01, 0.01]][:12 if name == "pm-tilt" else 10]
    model = build(name, ROBOT, data, x, start="nominal")
    r, W = model.evaluate(x)
    num = fd(lambda y: model.evaluate(y)[0], x, np.maximum(1e-6 * np.abs(x), 1e-9))
    assert_columns_close(W, -num, names=model.names)


# -- calibration from the report's nominal values (noise-free) ----------------------------
CASES = [("pm-ik", ABG, 14), ("pm-fk", ABG, 14), ("pm-fk", ("alpha", "beta"), 20),
         ("pm-fk", ("alpha",), 40)]


def check_classification(res, extra=()):
    labels = {s.name: s.label for s in res.status}
    for name in res.names:
        expected = INFLUENCES if name in ("q3_off", "k3") else IDENTIFIABLE
        assert labels[name] == expected, (name, labels)
    assert res.n_identifiable == 8 + len(extra)


@pytest.mark.parametrize("name, comps, m", CASES)
def test_converges_from_report_nominal_to_truth(name, comps, m):
    nominal = ROBOT.params({"q3_off": TRUE[6], "k3": TRUE[9]}, base=NOMINAL)
    res = solve(build(name, ROBOT, orientation_data(m, 20, comps), nominal))
    assert res.converged, res.message
    check_classification(res)
    np.testing.assert_allclose(res.x, TRUE, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name, comps, m", CASES)
def test_report_nominal_gives_an_equivalent_model(name, comps, m):
    res = solve(build(name, ROBOT, orientation_data(m, 21, comps), NOMINAL))
    assert res.converged, res.message
    check_classification(res)
    np.testing.assert_allclose(res.x, equivalent_truth(NOMINAL[6], NOMINAL[9]), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(ROBOT.ik_actuators(GRID, res.x), ROBOT.ik_actuators(GRID, TRUE),
                               rtol=0, atol=1e-6)


def test_pm_tilt_converges_and_identifies_the_mount():
    res = solve(build("pm-tilt", ROBOT, tilt_data(30, 22), np.r_[NOMINAL, 0.0, 0.0]))
    assert res.converged, res.message
    check_classification(res, extra=("mount_x", "mount_y"))
    np.testing.assert_allclose(res.x[:10], equivalent_truth(NOMINAL[6], NOMINAL[9]), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(res.x[10:], MOUNT, atol=1e-10)
    np.testing.assert_allclose(ROBOT.ik_actuators(GRID, res.x[:10]),
                               ROBOT.ik_actuators(GRID, TRUE), rtol=0, atol=1e-6)


# -- the compensation of q3_off, k3 (eqs. 112-113) -----------------------------------------
def test_different_nominal_q3_off_k3_give_the_same_actuators():
    data = orientation_data(20, 23, ("alpha", "beta"))
    models = []
    for q3, k3 in ((0.05, 1 / 8000), (-0.05, 1 / 10000), (0.0, 1 / 9000)):
        res = solve(build("pm-fk", ROBOT, data, ROBOT.params({"q3_off": q3, "k3": k3})))
        assert res.converged, res.message
        assert res.value("q3_off") == q3 and res.value("k3") == k3  # kept at nominal
        models.append(res.x)
    assert np.abs(models[0] - models[1]).max() > 1e-3  # really different models ...
    ref = ROBOT.ik_actuators(GRID, TRUE)
    for x in models:  # ... driving the robot alike
        np.testing.assert_allclose(ROBOT.ik_actuators(GRID, x), ref, rtol=0, atol=1e-6)


def test_operator_note_names_the_compensated_parameters():
    for cls in (InverseKinematics, ForwardKinematics):
        assert cls.notes == (COMPENSATION_NOTE,)
    assert Tilt.notes == (COMPENSATION_NOTE, HEADING_NOTE)
    note = compensation_note(0.0, 1e-4)
    assert "q3_off" in note and "k3" in note and "correct actuator values" in note
    assert "1/10000" in note


# -- noise ----------------------------------------------------------------------------------
def test_noisy_alpha_beta_within_reported_std_and_drives_the_robot():
    nominal = ROBOT.params({"q3_off": TRUE[6], "k3": TRUE[9]}, base=NOMINAL)
    # 1e-4 rad (0.006 deg): a good dual-axis inclinometer, averaged
    res = solve(build("pm-fk", ROBOT, orientation_data(40, 24, ("alpha", "beta"), 1e-4),
                      nominal))
    assert res.converged, res.message
    check_classification(res)
    ok = np.isfinite(res.std)
    assert np.all(np.abs(res.x - TRUE)[ok] < 3 * res.std[ok])
    assert 0.5e-4 < res.sigma["alpha"] < 2e-4
    err = np.abs(ROBOT.ik_actuators(GRID, res.x) - ROBOT.ik_actuators(GRID, TRUE)).max()
    assert err < 0.5  # actuator units (1 unit ~ 0.1 mm of slider travel)


# -- start values and input checks -----------------------------------------------------------
def test_robust_start_is_reachable_and_nominal_start_is_not():
    data = orientation_data(20, 25, ("alpha", "beta"))
    x = robust_start(ROBOT, data, NOMINAL, ("alpha", "beta"))
    assert x.shape == (10,)
    ROBOT.fk(data.qm, x)  # the start model assembles at every pose
    with pytest.raises(CalibrationError):  # the report's nominal PM cannot
        solve(build("pm-fk", ROBOT, data, NOMINAL, start="nominal"))


def test_bad_components_are_rejected():
    with pytest.raises(CalibrationError):
        parse_components(("beta", "alpha"))
    with pytest.raises(CalibrationError):
        parse_components(("yaw",))
    with pytest.raises(CalibrationError):
        build("pm-fk", ROBOT, orientation_data(5, 26, ("alpha", "beta")), NOMINAL,
              components=("alpha",), start="bogus")


def test_per_column_check_catches_a_three_percent_error_in_one_column():
    """pm-tilt's observation matrix spans orders of magnitude between columns
    (gear ratios against lengths): a 3 % error in the geometric column a1 is
    below one global tolerance of 1e-6 of the largest column, not below its own."""
    x = np.r_[equivalent_truth(0.01, 1 / 9500), [0.01, 0.01]]
    model = build("pm-tilt", ROBOT, tilt_data(6, 6), x, start="nominal")
    _, W = model.evaluate(x)
    num = -fd(lambda y: model.evaluate(y)[0], x, np.maximum(1e-6 * np.abs(x), 1e-9))
    j = model.names.index("a1")
    bad = W.copy()
    bad[:, j] *= 1.03
    np.testing.assert_allclose(bad, num, rtol=0, atol=1e-6 * np.abs(W).max())  # global: passes
    assert_columns_close(W, num, names=model.names)
    with pytest.raises(AssertionError, match="a1"):
        assert_columns_close(bad, num, names=model.names)


# -- pm-tilt does not identify the heading (docs/methods.md) --------------------------------
def _rz(phi):
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_the_inclinometer_does_not_see_the_heading():
    R = rot_xyz(GRID[::23])
    np.testing.assert_allclose(euler_xyz(R), GRID[::23], atol=1e-14)
    for phi in (0.2, -0.5):
        np.testing.assert_allclose(gravity_tilt(_rz(phi) @ R, MOUNT), gravity_tilt(R, MOUNT),
                                   rtol=0, atol=1e-14)
        assert np.abs(ROBOT.ik_actuators(euler_xyz(_rz(phi) @ R), TRUE)
                      - ROBOT.ik_actuators(GRID[::23], TRUE)).max() > 100  # ... the IK does


def test_ik_modulo_heading_takes_out_the_best_rotation_about_the_vertical():
    from scipy.optimize import minimize_scalar

    x = TRUE.copy()
    x[[0, 4]] += (1e-3, 2e-3)
    X = heading_grid()[::41]
    err, phi = ik_modulo_heading(ROBOT, X, x, TRUE)
    assert np.all(np.abs(phi) > 1e-4)
    q = ROBOT.ik_actuators(X, x)
    for i in range(len(X)):
        def gap(p):
            return ROBOT.ik_actuators(euler_xyz(_rz(p) @ rot_xyz(X[i])), TRUE)[0] - q[i]
        best = minimize_scalar(lambda p: np.sum(gap(p) ** 2), bounds=(-0.2, 0.2),
                               method="bounded", options={"xatol": 1e-12})
        assert abs(best.x - phi[i]) < 1e-8
        assert abs(np.abs(gap(best.x)).max() - err[i]) < 1e-6
    err0, phi0 = ik_modulo_heading(ROBOT, X, TRUE, TRUE)
    assert np.abs(err0).max() < 1e-9 and np.abs(phi0).max() < 1e-12


def test_heading_uncertainty_propagates_the_covariance():
    """The stated stds against finite differences of the IK and of the heading."""
    names = ("a1", "a2", "l", "v", "q1_off", "q2_off", "k1", "k2", "mount_x", "mount_y")
    scale = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-9, 1e-9, 1e-4, 1e-4])
    A = np.random.default_rng(3).normal(size=(10, 10))
    C = (A @ A.T + np.eye(10)) * np.outer(scale, scale)
    box = 15.0
    u = heading_uncertainty(ROBOT, TRUE, C, names, box_deg=box)
    X = heading_grid(box)
    J, Jh = np.zeros((len(X), 3, 10)), np.zeros((len(X), 10))
    for j, n in enumerate(names[:8]):
        h = 1e-3 * scale[j]
        xp, xm = TRUE.copy(), TRUE.copy()
        xp[ROBOT.index(n)] += h
        xm[ROBOT.index(n)] -= h
        J[..., j] = (ROBOT.ik_actuators(X, xp) - ROBOT.ik_actuators(X, xm)) / (2 * h)
        Jh[:, j] = (ik_modulo_heading(ROBOT, X, xp, TRUE)[1]
                    - ik_modulo_heading(ROBOT, X, xm, TRUE)[1]) / (2 * h)
    ik_std = np.sqrt(np.einsum("mak,kl,mal->ma", J, C, J)).max()
    heading_std = np.sqrt(np.einsum("mk,kl,ml->m", Jh, C, Jh)).max()
    assert u["ik_std"] == pytest.approx(ik_std, rel=1e-5)
    assert u["heading_std"] == pytest.approx(heading_std, rel=1e-4)
    assert u["ik_std_modulo_heading"] < 0.5 * u["ik_std"]


def test_pm_tilt_states_the_heading_as_not_identified():
    """A noisy pm-tilt fit: every parameter identifiable, the heading named with a
    std that covers the error of the calibrated IK's heading, the IK without it
    much closer than with it."""
    data = tilt_data(24, 31)
    rng = np.random.default_rng(8)
    data = MethodData(data.qm, {"tilt": data.channels["tilt"] + rng.normal(0, 7.6e-5, (24, 2))})
    model = build("pm-tilt", ROBOT, data, np.r_[NOMINAL, 0.0, 0.0])
    res = solve(model)
    assert res.converged and all(s.identifiable for s in res.status
                                 if s.name not in ("q3_off", "k3"))
    (d,) = model.unidentified_directions(res)
    assert d["direction"] == "heading" and d["box_deg"] == 15.0
    assert 1e-5 < d["std_rad"] < 0.05
    err, phi = ik_modulo_heading(ROBOT, heading_grid(), res.x[:10], TRUE)
    assert np.abs(phi).max() < 4 * d["std_rad"]
    assert err.max() < 4 * d["ik_std_modulo_heading"] < d["ik_std"]
