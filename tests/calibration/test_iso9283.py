"""ISO 9283 pose accuracy and repeatability (calibration/iso9283.py) against values
computed by hand."""
import math

import numpy as np
import pytest

from calibration import iso9283


def test_the_measuring_points_lie_on_the_diagonal_plane_at_a_tenth_of_the_diagonal():
    P = iso9283.measuring_points([1.0, 2.0, 3.0], 0.5)
    # by hand: half an edge 0.25, the points 0.8 of the way out: +-0.2 from the centre
    assert np.allclose(P, [[1.0, 2.0, 3.0], [0.8, 1.8, 2.8], [1.2, 1.8, 2.8],
                           [1.2, 2.2, 3.2], [0.8, 2.2, 3.2]])
    C = iso9283.cube_corners([1.0, 2.0, 3.0], 0.5)
    L = 0.5 * math.sqrt(3.0)                           # the diagonal
    for p, k in zip(P[1:], iso9283.PLANE_CORNERS):     # P2..P5 from C1, C2, C7, C8
        assert np.linalg.norm(p - C[k]) == pytest.approx(0.1 * L)
    # the plane C1-C2-C7-C8 holds every point: normal (0, 1, -1) through the centre
    assert np.allclose((P - [1.0, 2.0, 3.0]) @ [0.0, 1.0, -1.0], 0.0)
    assert np.allclose(C[[0, 1, 6, 7]] @ [0.0, 1.0, -1.0] - (2.0 - 3.0), 0.0)


def test_a_turned_cube_turns_its_points():
    Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    P = iso9283.measuring_points([0, 0, 0], 1.0, Rz)
    assert np.allclose(P[1], Rz @ [-0.4, -0.4, -0.4])
    with pytest.raises(ValueError):
        iso9283.measuring_points([0, 0, 0], 1.0, np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError):
        iso9283.cube_corners([0, 0, 0], 0.0)


def test_pose_accuracy_and_repeatability_by_hand():
    # four attained positions about a barycentre (1, 2, 3) + (0.1, 0, 0), commanded (1, 2, 3)
    att = np.array([[1.1, 2.0, 3.0], [1.1, 2.0, 3.0], [1.1, 2.0, 3.0], [1.1, 2.0, 3.0]])
    att += np.array([[0.03, 0.0, 0.0], [-0.03, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, -0.04, 0.0]])
    ap, d = iso9283.accuracy(att, [1.0, 2.0, 3.0])
    assert ap == pytest.approx(0.1) and np.allclose(d, [0.1, 0.0, 0.0])
    rp, lbar, s = iso9283.repeatability(att)
    # l_j = 0.03, 0.03, 0.04, 0.04: l-bar 0.035, S_l = sqrt(4 * 0.005^2 / 3)
    assert lbar == pytest.approx(0.035)
    assert s == pytest.approx(math.sqrt(4 * 0.005 ** 2 / 3))
    assert rp == pytest.approx(0.035 + 3 * math.sqrt(4 * 0.005 ** 2 / 3))
    r = iso9283.pose_result("P3", att, [1.0, 2.0, 3.0])
    assert (r.name, r.n, r.ap_abc) == ("P3", 4, None) and r.rp == pytest.approx(rp)
    with pytest.raises(ValueError):
        iso9283.repeatability(att[:1])


def _rot(axis, a):
    c, s = math.cos(a), math.sin(a)
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def test_orientation_accuracy_and_repeatability_by_hand():
    Rc = _rot("z", 0.7) @ _rot("x", 0.2)             # any commanded orientation
    # attained: turned about the frame's x by 1, 3 mrad, about z by -2, 2 mrad
    att = [_rot("x", 1e-3) @ Rc, _rot("x", 3e-3) @ Rc, _rot("z", -2e-3) @ Rc,
           _rot("z", 2e-3) @ Rc]
    ang = iso9283.deviation_angles(Rc, np.array(att))
    assert np.allclose(ang, [[1e-3, 0, 0], [3e-3, 0, 0], [0, 0, -2e-3], [0, 0, 2e-3]], atol=1e-12)
    ap, rp = iso9283.orientation(ang)
    assert np.allclose(ap, [1e-3, 0.0, 0.0])
    # a: 1, 3, 0, 0 mrad: mean 1, S = sqrt((0 + 4 + 1 + 1) / 3) mrad
    assert rp[0] == pytest.approx(3 * math.sqrt(6 / 3) * 1e-3)
    assert rp[1] == pytest.approx(0.0, abs=1e-12) and rp[2] == pytest.approx(3 * math.sqrt(8 / 3) * 1e-3)
    # about other axes: the base frame turned by 90 deg about z in the instrument's
    B = _rot("z", math.pi / 2)
    one = iso9283.deviation_angles(Rc, _rot("x", 1e-3) @ Rc, B)
    assert np.allclose(one, [0.0, -1e-3, 0.0], atol=1e-12)      # x is the base's -y
