"""URDF robots (calibration.robots.urdf) and points on the tool (sm-markers): forward
kinematics against a standard URDF parser, the observation matrix against finite
differences, what is identifiable, and a result that does not depend on how the
instrument's frame is turned."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calibration.methods import MethodData, build
from calibration.methods.sm_markers import marker_names, register, scale_and_mirror
from calibration.robots import get_robot
from calibration.robots.serial import rpy_of
from calibration.solver import SolverOptions, solve
from drivers.urdf_file import load_urdf
from station.simulation import tracegen_urdf as tg

URDF = Path(__file__).resolve().parents[2] / "fixtures" / "robots" / "m10ia-like.urdf"


def arm():
    return get_robot(load_urdf(URDF, "base_link", "tool0"))


def case(seed=1, count=40, points=3, noise=3e-5, unseen=0.0, frame=None):
    """A drawn arm seen by a tracker: ``(robot, truth x, qm, readings)``."""
    rob = arm()
    rng = np.random.default_rng(seed)
    x = tg.draw_truth(rob, rng)
    R, t = tg.draw_frame(rng, vertical_tilt_deg=0.6) if frame is None else frame
    x = tg.frame_parameters(rob, x, R, t)
    u = tg.draw_points(rng, points)
    qm = tg.draw_poses(rob, count, rng)
    P = tg.readings(rob, x, u, qm, rng, noise, unseen=unseen)
    return rob, np.r_[x, u.reshape(-1)], qm, P


def start(rob, qm, P):
    """The importer's start values: the instrument frame and points registered."""
    R, t, u, _ = register(rob, qm, P, rob.nominal)
    x = rob.nominal.copy()
    for n, v in zip(("base_x", "base_y", "base_z"), t):
        x[rob.index(n)] = v
    for n, v in zip(("base_roll", "base_pitch", "base_yaw"), rpy_of(R[None])[0]):
        x[rob.index(n)] = v
    return np.r_[x, u.reshape(-1)]


def fit(rob, qm, P, x0=None):
    model = build("sm-markers", rob, MethodData(qm=qm, channels={"markers": P}),
                  start(rob, qm, P) if x0 is None else x0)
    return model, solve(model, SolverOptions(fixed=rob.fixed))


def test_forward_kinematics_equal_a_standard_parser():
    import yourdfpy
    rob = arm()
    u = yourdfpy.URDF.load(str(URDF), load_meshes=False)
    qm = tg.draw_poses(rob, 30, np.random.default_rng(0), margin=0.0)
    T = rob.frames(qm, rob.nominal)
    for q, Ti in zip(qm, T):
        u.update_cfg(dict(zip(rob.spec.joint_names, q)))
        assert np.abs(u.get_transform("tool0", "base_link") - Ti).max() < 1e-12


def test_the_chain_takes_the_urdf_s_axes_limits_and_fixed_joints():
    rob = arm()
    assert rob.spec.joint_names == tuple(f"joint_{i}" for i in range(1, 7))
    assert rob.spec.joints[2].axis == (0.0, -1.0, 0.0) and rob.spec.joints[3].axis == (-1.0, 0.0, 0.0)
    assert rob.limits[1].tolist() == [-1.57, 2.79]
    assert set(rob.fixed) == {"base_roll", "base_pitch", "base_yaw", *(f"k{i}" for i in range(1, 7))}
    # the base link is not the URDF's root ("world"): the chain starts where it is told
    assert load_urdf(URDF, "world", "tool0").joints[0].name == "joint_1"


def _fd(model, x, h=1e-7):
    J = np.empty((len(model.evaluate(x)[0]), len(x)))
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h
        J[:, j] = -(model.evaluate(x + e)[0] - model.evaluate(x - e)[0]) / (2 * h)
    return J


def test_observation_matrix_matches_finite_differences_with_points_unseen():
    rob, x, qm, P = case(seed=3, count=8, unseen=0.3)
    assert np.isnan(P).any()
    model, _ = fit(rob, qm, P, x0=x)
    rng = np.random.default_rng(4)
    xs = x + rng.normal(0, 0.01, x.size)
    W = model.evaluate(xs)[1]
    Jn = _fd(model, xs)
    assert W.shape == (3 * int(np.sum(~np.isnan(P[..., 0]))), rob.n_params + 9)
    for j, n in enumerate(model.names):
        scale = max(np.linalg.norm(Jn[:, j]), 1e-9)
        assert np.linalg.norm(W[:, j] - Jn[:, j]) <= 1e-6 * scale + 1e-8, n


def test_what_a_tracker_identifies_on_a_6r_arm():
    rob, x, qm, P = case(seed=5, count=40)
    model, res = fit(rob, qm, P)
    kept = {s.name for s in res.status if s.identifiable}
    # eq. 8: 4 n_R + 6 = 30 with the base and the tool; three points on the tool carry
    # the tool's 6 and 3 of their own: 33
    assert res.converged and res.n_identifiable == 33
    # the instrument frame and the points are judged first: they keep what they absorb
    assert {"base_x", "base_y", "base_z", "base_rx", "base_ry", "base_rz"} <= kept
    assert set(marker_names(3)) <= kept
    assert not kept & {"q1_off", "q6_off", "j1_x", "j1_y", "j1_z", "j1_rx", "j1_ry", "j1_rz"}
    # held values stay exactly where they were
    for n in rob.fixed:
        assert res.x[model.names.index(n)] == model.x0[model.names.index(n)]


def test_noise_free_fit_finds_the_truth_s_equivalent():
    rob, x, qm, P = case(seed=6, count=30, noise=0.0)
    model, res = fit(rob, qm, P)
    r, _ = model.evaluate(res.x)
    assert res.converged and np.abs(r).max() < 1e-10
    # the same arm, seen anywhere: the tool where the truth puts it, on new poses
    q2 = tg.draw_poses(rob, 20, np.random.default_rng(9))
    n = rob.n_params
    for xx in (x, res.x):
        T = rob.frames(q2, xx[:n])
        pts = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], xx[n:].reshape(-1, 3))
        if xx is x:
            ref = pts
    assert np.abs(pts - ref).max() < 1e-9


@pytest.mark.parametrize("seed", [7, 8])
def test_the_result_does_not_depend_on_how_the_instrument_is_turned(seed):
    rob, x, qm, P = case(seed=seed, count=40, unseen=0.05)
    rng = np.random.default_rng(seed + 100)
    Q = tg.draw_frame(rng)[0]
    # the same readings in a frame turned anywhere, and one whose z is the base's
    # axis exactly (joint 1 parallel to the instrument's z)
    flat = tg.draw_frame(rng, vertical_tilt_deg=0.0)[0]
    Rb = tg.draw_frame(np.random.default_rng(seed), vertical_tilt_deg=0.6)[0]
    for turn in (Q, flat @ Rb.T):
        P2 = np.einsum("ij,mkj->mki", turn, P) + np.array([3.0, -2.0, 1.0])
        m1, a = fit(rob, qm, P)
        m2, b = fit(rob, qm, P2)
        robot_part = [j for j, n in enumerate(a.names) if not n.startswith("base_")]
        assert [s.identifiable for s in a.status] == [s.identifiable for s in b.status]
        scale = np.maximum(np.abs(a.x[robot_part]), 1e-3)
        assert np.max(np.abs(a.x[robot_part] - b.x[robot_part]) / scale) < 1e-6
        assert a.std[robot_part] == pytest.approx(b.std[robot_part], rel=1e-6, nan_ok=True)
        ra, rb = m1.evaluate(a.x)[0], m2.evaluate(b.x)[0]
        assert np.sqrt(np.mean(rb ** 2)) == pytest.approx(np.sqrt(np.mean(ra ** 2)), rel=1e-9)


def test_scale_and_mirror_are_what_a_person_checks_first():
    rob, x, qm, P = case(seed=11, count=30)
    scale, proper, mirrored = scale_and_mirror(rob, qm, P, rob.nominal)
    assert 0.7 < scale < 1.4 and proper < 0.02
    s_mm = scale_and_mirror(rob, qm, P * 1000.0, rob.nominal)[0]
    assert 700 < s_mm < 1400
    flipped = P.copy()
    flipped[..., 0] *= -1
    _s, proper_f, mirrored_f = scale_and_mirror(rob, qm, flipped, rob.nominal)
    assert mirrored_f < proper_f / 10 and mirrored_f < 0.02


def test_a_urdf_and_a_robot_file_are_one_model():
    """Both written forms make the one serial-chain model; what only a URDF's model
    offers (its origins, its frame, its labels) is there for it alone, also after a
    pickle's round trip."""
    import pickle

    from calibration.robots.serial import SerialRobot
    from calibration.robots.urdf import UrdfRobot
    from drivers.robot_file import load_robot_file

    urdf = arm()
    dh = get_robot(load_robot_file(URDF.parent / "ur5-like-hayati.toml"))
    assert type(urdf) is type(dh) is SerialRobot and UrdfRobot is SerialRobot
    for name in ("calibrated_origins", "frame_matrix", "held_reason", "joint_label"):
        assert hasattr(urdf, name) and not hasattr(dh, name), name
    twin = pickle.loads(pickle.dumps(urdf))
    assert twin.joint_label(1) == urdf.joint_label(1) and twin.fixed == urdf.fixed
    assert np.array_equal(twin.frame_matrix(urdf.nominal), np.eye(4))
    assert urdf.warnings(urdf.nominal) == () and urdf.loads(np.zeros((1, 6))) is None


def compliant_arm(payload=None):
    from drivers.urdf_file import parse_urdf

    return get_robot(parse_urdf(URDF.read_text(), str(URDF), "base_link", "tool0",
                                compliance=True, payload=payload))


def test_gravity_loads_are_the_potential_energy_s_slope():
    """tau_i = -dV/dq_i, V the links' and the payload's potential energy in gravity along
    the base link's -z (checked against the centres of mass moved by finite steps)."""
    rob = compliant_arm({"mass": 2.0, "com": [0.05, 0.0, 0.1]})
    qm = tg.draw_poses(rob, 4, np.random.default_rng(2), margin=0.0)
    tau = rob.loads(qm)

    # potential of the lumped bodies, each body carried rigidly by its joint's child frame
    from calibration.robots.urdf import GRAVITY, joint_pieces

    pieces, tail = joint_pieces(rob.spec)
    motion = [j for j, f in enumerate(rob.chain.factors) if f.joint is not None]

    def V(q):
        _T, before = rob.chain.frames(q[None], rob.nominal)
        total = 0.0
        for i, (jt, f) in enumerate(zip(rob.spec.joints, motion)):
            M = np.eye(4)
            c, s = np.cos(q[i]), np.sin(q[i])
            M[:2, :2] = [[c, -s], [s, c]]
            child = before[0, f] @ M @ pieces[i][1].T
            com, mass = np.asarray(jt.com), jt.mass
            if i == len(motion) - 1:
                pm, pc = rob.spec.payload
                com = (mass * com + pm * (np.asarray(tail) @ np.r_[pc, 1.0])[:3]) / (mass + pm)
                mass += pm
            total += mass * GRAVITY * (child[:3, :3] @ com + child[:3, 3])[2]
        return total

    h = 1e-6
    for q, t in zip(qm, tau):
        fd = [-(V(q + h * e) - V(q - h * e)) / (2 * h) for e in np.eye(6)]
        assert np.abs(np.array(fd) - t).max() < 1e-6 * max(1.0, np.abs(t).max())
    assert abs(tau[:, 0]).max() < 1e-9          # joint 1's axis is vertical: no torque


def test_compliance_columns_match_finite_differences():
    rob = compliant_arm()
    rng = np.random.default_rng(3)
    x = tg.draw_compliance(rob, tg.draw_truth(rob, rng), rng)
    qm = tg.draw_poses(rob, 6, rng)
    u = tg.draw_points(rng, 2)
    P = tg.readings(rob, x, u, qm, rng, 0.0)
    xs = np.r_[x, u.reshape(-1)]
    model = build("sm-markers", rob, MethodData(qm=qm, channels={"markers": P}), xs)
    W = model.evaluate(xs)[1]
    Jn = _fd(model, xs, h=1e-8)
    for i in range(1, 7):
        j = model.names.index(f"c{i}")
        assert np.linalg.norm(W[:, j] - Jn[:, j]) <= 1e-6 * max(np.linalg.norm(Jn[:, j]), 1.0)


def test_the_rows_of_many_poses_are_made_in_blocks_the_same_bit_for_bit(monkeypatch):
    """100 000 poses of three points are a 900 000-row matrix; evaluated a block of poses
    at a time, its temporaries stay small. The rows are those of one block, exactly."""
    import calibration.methods.sm_markers as sm

    rob, x, qm, P = case(seed=5, count=50, unseen=0.3)
    model = build("sm-markers", rob, MethodData(qm=qm, channels={"markers": P}), x)
    whole = model.evaluate(x)
    for block in (1, 7, 49):
        monkeypatch.setattr(sm, "POSE_BLOCK", block)
        r, W = model.evaluate(x)
        assert np.array_equal(r, whole[0]) and np.array_equal(W, whole[1]), block
