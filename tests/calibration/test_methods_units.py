"""Known answers for the parts of calibration/methods that the session-sized tests
reach only through a whole fit: the method registry's lookups, sm-plane's start
plane (eq. 74) and the PM methods' operator notes with the values the result
refers to. Milliseconds each; bench/mutation.py methods runs them (with
tests/calibration/test_serial.py, which checks the robot-file methods'
Jacobians column by column)."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.methods import METHODS, MethodData, build, extra_params, methods_for
from calibration.methods.pm_common import COMPENSATION_NOTE
from calibration.methods.pm_fk import ForwardKinematics
from calibration.methods.pm_ik import InverseKinematics
from calibration.methods.pm_tilt import HEADING_NOTE, Tilt
from calibration.methods.sm_plane import plane_through
from calibration.robots import get_robot
from calibration.robots.agebot_pm import AgebotPM
from tests.calibration.serial_helpers import data_of, robot

SM = ("sm-full-pose", "sm-position", "sm-distance", "sm-self-redundancy", "sm-plane",
      "sm-distance-tilt")


# -- the registry --------------------------------------------------------------------------
def test_methods_for_each_kind_in_registry_order():
    assert methods_for(get_robot("agebot-sm")) == SM
    assert methods_for(AgebotPM()) == ("pm-ik", "pm-fk", "pm-tilt")
    assert methods_for(robot("scara-like")) == SM          # a robot file is a serial arm
    # points on the tool in an unknown instrument frame: URDF robots only
    from tests.calibration.test_urdf import arm

    assert methods_for(arm()) == SM + ("sm-markers",)
    assert set(methods_for(get_robot("agebot-sm"))) | {"pm-ik", "pm-fk", "pm-tilt",
                                                       "sm-markers"} == set(METHODS)


@pytest.mark.parametrize("method, builtin, on_file", [
    ("sm-distance-tilt", (), ("mount_x", "mount_y")),
    ("sm-plane", ("plane_a", "plane_b", "plane_c"), ("plane_a", "plane_b", "plane_c")),
    ("sm-position", (), ()), ("sm-distance", (), ())])
def test_extra_params_on_a_builtin_and_on_a_robot_file(method, builtin, on_file):
    assert extra_params(method, get_robot("agebot-sm")) == builtin
    assert extra_params(method, robot("ur5-like-hayati")) == on_file
    assert extra_params("pm-tilt", AgebotPM()) == ("mount_x", "mount_y")
    with pytest.raises(CalibrationError, match="unknown method 'sm-laser'"):
        extra_params("sm-laser", AgebotPM())


# -- sm-plane's start plane (eq. 74) --------------------------------------------------------
def test_plane_through_points_on_a_plane_is_that_plane():
    rng = np.random.default_rng(3)
    abc = np.array([0.4, -1.5, 2.5])
    xy = rng.uniform(-0.5, 0.5, (7, 2))
    z = -(1.0 + xy @ abc[:2]) / abc[2]                 # a x + b y + c z + 1 = 0
    np.testing.assert_allclose(plane_through(np.column_stack([xy, z])), abc, rtol=1e-12)


def test_plane_through_is_the_least_squares_plane():
    """Points 1 mm above and below z = -0.5 at mirrored x, y: eq. 74's plane is
    level, a = b = 0, with c = -sum z / sum z^2 (its algebraic residual, not the
    points' distance: 1.999992, not 2)."""
    xy = np.array([[0.1, 0.2], [-0.1, -0.2], [0.3, -0.1], [-0.3, 0.1]])
    z = -0.5 + np.array([1e-3, 1e-3, -1e-3, -1e-3])
    np.testing.assert_allclose(plane_through(np.column_stack([xy, z])),
                               [0.0, 0.0, -z.sum() / (z ** 2).sum()], rtol=1e-12, atol=1e-12)
    # more rows than needed: the same answer as the normal equations
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(20, 3))
    normal = np.linalg.solve(pts.T @ pts, -pts.sum(axis=0))
    np.testing.assert_allclose(plane_through(pts), normal, rtol=1e-10)


def test_plane_start_is_the_plane_through_the_contacts():
    """sm-plane without a given plane starts from the plane through the nominal
    model's contact points; a given plane is kept as the start."""
    rob = robot("scara-like")
    data, header = data_of(rob, "sm-plane", rob.nominal, seed=1, count=12)
    given = [header["nominal"][k] for k in ("plane_a", "plane_b", "plane_c")]
    nominal = np.r_[rob.nominal, given]
    fresh = build("sm-plane", rob, data, nominal)
    pts = rob.fk(data.qm, rob.nominal)[:, :3]
    np.testing.assert_allclose(fresh.x0[rob.n_params:], plane_through(pts), rtol=1e-12)
    np.testing.assert_allclose(fresh.x0[rob.n_params:], given, rtol=1e-6)  # noise-free contacts
    np.testing.assert_array_equal(fresh.x0[:rob.n_params], rob.nominal)
    kept = build("sm-plane", rob, data, np.r_[rob.nominal, 0.1, 0.2, 0.3], plane_given=True)
    np.testing.assert_array_equal(kept.x0[rob.n_params:], [0.1, 0.2, 0.3])


# -- the PM methods' notes with the values the result refers to -----------------------------
def _pm_data(n=6):
    from tests.calibration.test_pm import orientation_data, tilt_data
    return orientation_data(n, 5), tilt_data(n, 5)


@pytest.mark.parametrize("name, cls", [("pm-ik", InverseKinematics), ("pm-fk", ForwardKinematics),
                                       ("pm-tilt", Tilt)])
def test_operator_notes_name_the_q3_off_and_k3_of_the_result(name, cls):
    rob = AgebotPM()
    orient, tilt = _pm_data()
    nominal = rob.nominal if name != "pm-tilt" else np.r_[rob.nominal, 0.0, 0.0]
    model = build(name, rob, tilt if name == "pm-tilt" else orient, nominal,
                  **({"start": "nominal"} if name == "pm-tilt" else {}))
    assert isinstance(model, cls)
    iq, ik = rob.index("q3_off"), rob.index("k3")
    x = model.x0.copy()
    x[iq], x[ik] = 0.0123, 2.5e-4
    notes = model.operator_notes(x)
    assert notes[0] == (COMPENSATION_NOTE + " This calibration refers to q3_off = 0.0123, "
                        "k3 = 0.00025 (1/4000).")
    assert notes[1:] == ((HEADING_NOTE,) if name == "pm-tilt" else ())
    # without values: the start values
    at_start = model.operator_notes()
    assert f"q3_off = {model.x0[iq]:.6g}," in at_start[0]
    assert f"k3 = {model.x0[ik]:.6g} (1/{1.0 / model.x0[ik]:.6g})." in at_start[0]
    assert len(at_start) == len(notes)


def test_a_method_refuses_the_other_kind_of_robot():
    orient, _ = _pm_data()
    with pytest.raises(CalibrationError, match="pm-fk needs a parallel-wrist robot"):
        build("pm-fk", get_robot("agebot-sm"), orient, get_robot("agebot-sm").nominal)
    with pytest.raises(CalibrationError, match="sm-position needs a serial robot"):
        build("sm-position", AgebotPM(), MethodData(orient.qm, {"position": np.zeros((6, 3))}),
              AgebotPM().nominal)


# -- the robot-file sm-distance-tilt's distance rows (known answers) ---------------------------
@pytest.mark.parametrize("residual", ["plain", "squared"])
def test_inclinometer_distance_rows_are_the_reading_minus_the_model_s_distance(residual):
    """Distance rows: the reading against |p - p_reference| + distance_off (plain) or
    their squares (eq. 83); rows per pose distance, roll, pitch."""
    from calibration.methods.sm_distance_tilt import InclinometerDistanceTilt
    rob = robot("ur5-like-hayati")
    data, _ = data_of(rob, "sm-distance-tilt", rob.nominal, seed=1, count=6, mount=(0.02, -0.01))
    model = build("sm-distance-tilt", rob, data, np.r_[rob.nominal, 0.0, 0.0],
                  distance_zero="reading", residual=residual)
    assert isinstance(model, InclinometerDistanceTilt)
    assert model.names[rob.n_params:] == ("distance_off", "mount_x", "mount_y")
    assert model.channels == ("distance", "roll", "pitch")
    np.testing.assert_array_equal(model.row_channel, np.tile([0, 1, 2], 6))
    x = model.x0.copy()
    x[rob.n_params] = 2e-3                                   # the draw-wire's zero offset
    r = model.evaluate(x)[0].reshape(6, 3)
    p = rob.fk(data.qm, x[:rob.n_params])[:, :3]
    p_ref = rob.fk(np.atleast_2d(data.reference_qm), x[:rob.n_params])[0, :3]
    pred = np.linalg.norm(p - p_ref, axis=1) + 2e-3
    D_m = data.channels["distance"].reshape(-1)
    want = D_m - pred if residual == "plain" else D_m ** 2 - pred ** 2
    np.testing.assert_allclose(r[:, 0], want, rtol=1e-9, atol=1e-15)
    # the tilt rows do not see the draw-wire's zero
    x0 = x.copy()
    x0[rob.n_params] = 0.0
    np.testing.assert_array_equal(model.evaluate(x0)[0].reshape(6, 3)[:, 1:], r[:, 1:])


def test_inclinometer_and_position_channels_are_checked():
    rob = robot("scara-like")
    data, _ = data_of(rob, "sm-distance-tilt", rob.nominal, seed=1, count=6)
    bad = MethodData(data.qm, {**data.channels, "tilt": data.channels["tilt"][:, :1]},
                     reference_qm=data.reference_qm)
    with pytest.raises(CalibrationError, match=r"channel 'tilt' must have shape \(poses, 2\)"):
        build("sm-distance-tilt", rob, bad, np.r_[rob.nominal, 0.0, 0.0])
    with pytest.raises(CalibrationError, match="method sm-position needs the measured channel "
                                               "'position'"):
        build("sm-position", rob, MethodData(data.qm, {}), rob.nominal)
