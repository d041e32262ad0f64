"""Poses for a point instrument (station/planning/marker_plan.py): an industrial arm seen by
a tracker 2.9 m away in a z-up room, three reflectors on the tool's face. Every planned
pose is checked here independently of the planner's own visibility test: joint limits
with the margin, every point in the measuring volume and facing the tracker, the tool
above the floor; the D-optimal choice, the rounds, the scout's registration."""
from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from calibration import design as dz
from calibration.errors import CalibrationError
from calibration.methods.sm_markers import register, tip_frames
from calibration.robots import get_robot
from drivers.urdf_file import load_urdf
from station.planning import marker_plan as mp
from station.planning import pose_design as pd
from station.planning.arm_rounds import SCOUT_SCALE
from station.planning.request import PlanRequest
from station.planning.serial_plan import FLOOR_MARGIN
from station.simulation import tracegen_urdf as tg

URDF = Path(__file__).resolve().parents[2] / "fixtures" / "robots" / "m10ia-like.urdf"
ANGLE = math.radians(80)


@lru_cache(maxsize=None)
def _robot():
    return get_robot(load_urdf(URDF, "base_link", "tool0"))


def _case(seed: int = 3, *, exact: bool = False, half=(1.7, 1.7, 1.3), angle=ANGLE):
    """``(robot, truth x, points (3, 3), sight)``: the instrument's frame drawn z-up (as
    tracegen_urdf draws it), its origin (the tracker's head) 2.9 m in front of the robot
    and 1 m above the base's floor, the volume a box about the robot's reach."""
    rob = _robot()
    rng = np.random.default_rng(seed)
    R, _ = tg.draw_frame(rng, vertical_tilt_deg=0.5)
    head = np.array([2.8, 0.6, 1.0])                 # the tracker in the base link's frame
    x = rob.nominal if exact else tg.draw_truth(rob, rng)
    x = tg.frame_parameters(rob, x, R, -R @ head)
    u = tg.draw_points(rng, 3)
    u[:, 2] = np.abs(u[:, 2]) + 0.03                  # on the tool's face (its z leaves it)
    centre = R @ np.array([0.0, 0.0, 0.9]) - R @ head
    sight = mp.Sight(centre - half, centre + half, (0.0, 0.0, 0.0), angle)
    return rob, x, u, sight


def _independent_checks(rob, x, u, sight, qm, *, facing=True, margin=mp.MARGIN):
    """The plan's poses checked without the planner's code: limits less the margin, the
    tool above the base's floor, each point inside the volume and within max_angle."""
    lo, hi = rob.limits[:, 0], rob.limits[:, 1]
    span = hi - lo
    assert np.all(qm >= lo + margin * span - 1e-12) and np.all(qm <= hi - margin * span + 1e-12)
    T = tip_frames(rob, qm, x)                         # the tip in the base link's frame
    assert np.all(T[:, 2, 3] >= FLOOR_MARGIN)
    F = rob.frame_matrix(x)                            # the base in the instrument's frame
    for Ti in T:
        G = F @ Ti
        for p in u:
            q = G[:3, :3] @ p + G[:3, 3]
            assert np.all(q >= sight.volume_min) and np.all(q <= sight.volume_max)
            if facing:
                out = G[:3, :3] @ (p / np.linalg.norm(p))
                los = np.asarray(sight.viewpoint) - q
                cos = out @ los / np.linalg.norm(los)
                assert math.acos(min(1.0, cos)) <= sight.max_angle + 1e-9


def _logdet(rob, x, u, qm, names):
    model = pd.pool_model("sm-markers", rob, np.r_[x, u.ravel()], qm)
    info = dz.pose_information(model, model.x0, pd.DEFAULT_NOISE, names=names)
    return np.linalg.slogdet(info.matrix(np.arange(info.size), scaled=False))[1]


def _fit(qm, use):
    return qm[np.array(use) == "fit"]


def _within(rob, qm, scale):
    """Every pose inside the limits less the margin shrunk by ``scale`` about home."""
    home, box = mp.home_qm(rob), mp.limit_box(rob)
    near = home[:, None] + scale * (box - home[:, None])
    return bool(np.all((qm >= near[:, 0] - 1e-12) & (qm <= near[:, 1] + 1e-12)))


def test_every_planned_pose_is_inside_the_limits_above_the_floor_and_seen():
    rob, x, u, sight = _case()
    qm, use, design = mp.plan(rob, x, u, sight, PlanRequest(count=24, validation=6, seed=1))
    assert (use.count("fit"), use.count("validation")) == (24, 6) and len(qm) == 30
    _independent_checks(rob, x, u, sight, qm)
    assert mp.visible(rob, x, u, sight, qm).all()
    assert design["design"] == "optimal" and design["poses"] == 24
    assert design["predicted_heldout"]["what"] == "position"
    # the default count: twice eq. 60 over what the pool identifies (3 points: 9 rows)
    qm, use, design = mp.plan(rob, x, u, sight, PlanRequest(seed=2))
    n_ident = len(design["predicted_std"])
    assert use.count("fit") >= 2 * math.ceil(5 * (n_ident - 2) / 9)
    assert use.count("validation") == max(3, use.count("fit") // 5)
    _independent_checks(rob, x, u, sight, qm)


def test_d_optimal_beats_random():
    rob, x, u, sight = _case()
    req = PlanRequest(count=20, validation=0, seed=4)
    q_opt, use_opt, d_opt = mp.plan(rob, x, u, sight, req)
    q_rnd, use_rnd, d_rnd = mp.plan(rob, x, u, sight, PlanRequest(count=20, validation=0,
                                                                    seed=4, design="random"))
    names = tuple(d_opt["predicted_std"])
    assert _logdet(rob, x, u, _fit(q_opt, use_opt), names) > \
        _logdet(rob, x, u, _fit(q_rnd, use_rnd), names) + 1.0
    common = [n for n in names if n in d_rnd["predicted_std"]]

    def gm(d):
        return dz.geometric_mean_std(np.array([d["predicted_std"][n] or np.inf for n in common]))

    assert gm(d_opt) < gm(d_rnd)
    assert d_opt["observability"]["O1"] > d_rnd["observability"]["O1"]


@pytest.mark.parametrize("half, angle, worst", [((0.15, 0.15, 0.15), ANGLE, "volume"),
                                                ((1.7, 1.7, 1.3), math.radians(3), "facing")])
def test_too_few_visible_poses_is_one_line_naming_the_condition(half, angle, worst):
    rob, x, u, sight = _case(half=half, angle=angle)
    with pytest.raises(CalibrationError) as e:
        mp.plan(rob, x, u, sight, PlanRequest(count=20, validation=5))
    text = str(e.value)
    assert "\n" not in text and f"most failed on {worst}" in text
    assert "keep every point visible" in text and f"of {mp.MAX_DRAWS + mp.POOL} poses" in text


def test_rounds_grow_about_home_and_sequential_design_adds_to_the_measured():
    rob, x, u, sight = _case()
    assert np.allclose(mp.home_qm(rob), 0.0)   # the URDF's zero: inside every joint's limits
    q1, use1, d1 = mp.plan(rob, x, u, sight, PlanRequest(count=12, validation=0, seed=5),
                           scale=0.3)
    assert _within(rob, q1, 0.3)
    _independent_checks(rob, x, u, sight, q1)
    measured = _fit(q1, use1)
    q2, use2, d2 = mp.plan(rob, x, u, sight, PlanRequest(count=16, validation=4, seed=6),
                           start_qm=measured[-1], measured_qm=measured)
    _independent_checks(rob, x, u, sight, q2)
    assert d2["poses"] == 12 + 16
    new = _fit(q2, use2)
    assert not any(np.allclose(a, b) for a in new for b in measured)
    assert not _within(rob, q2, 0.3)                     # the whole box this time
    names = tuple(d2["predicted_std"])
    # given the measured poses, the design's poses add more than random ones would
    _, use_r, _ = qr = mp.plan(rob, x, u, sight, PlanRequest(count=16, validation=4, seed=6,
                                                           design="random"),
                               start_qm=measured[-1], measured_qm=measured)
    assert _logdet(rob, x, u, np.vstack([measured, new]), names) > \
        _logdet(rob, x, u, np.vstack([measured, _fit(qr[0], use_r)]), names)


def test_the_config_s_limits_narrow_the_box():
    rob, x, u, sight = _case()
    qm_range = rob.limits.copy()
    qm_range[0] = (-0.5, 0.8)
    qm, _, _ = mp.plan(rob, x, u, sight, PlanRequest(count=12, validation=2, seed=7),
                       qm_range=qm_range)
    assert np.all((qm[:, 0] >= -0.5) & (qm[:, 0] <= 0.8))
    _independent_checks(rob, x, u, sight, qm)


@pytest.mark.parametrize("seed", [3, 11])
def test_the_scout_lets_register_place_the_frame_and_the_points(seed):
    rob, x, u, sight = _case(seed)
    half = 0.5 * np.diff(mp.limit_box(rob), axis=1)[:, 0]
    # nothing known: the URDF's values, no frame, no points
    qm, use, _ = mp.scout(rob, rob.nominal, None, sight, PlanRequest(seed=seed),
                          frame_known=False)
    assert 8 <= len(qm) <= 10 and set(use) == {"fit"}
    assert _within(rob, qm, SCOUT_SCALE)
    assert np.all(np.std(qm, axis=0) > 0.25 * SCOUT_SCALE * half)      # every joint moves
    _independent_checks(rob, x, u, sight, qm, facing=False)
    P = tg.readings(rob, x, u, qm, np.random.default_rng(0), 0.0)      # noise-free
    R, t, u_est, _ = register(rob, qm, P, rob.nominal)
    F = rob.frame_matrix(x)
    turn = math.acos(min(1.0, (np.trace(R.T @ F[:3, :3]) - 1) / 2))
    # the drawn robot's joint zeros (5 mrad) and origins (1 mm) are what the frame takes up
    # (60 poses over the whole box place it no better: 1-3 mm, 3-7 mrad)
    assert np.linalg.norm(t - F[:3, 3]) < 5e-3 and turn < 8e-3
    assert np.abs(u_est - u).max() < 5e-3
    # the robot as its URDF says: the frame exactly
    rob, x, u, sight = _case(seed, exact=True)
    R, t, _, _ = register(rob, qm, tg.readings(rob, x, u, qm, np.random.default_rng(0), 0.0),
                          rob.nominal)
    assert np.allclose(t, rob.frame_matrix(x)[:3, 3], atol=1e-9)


def test_a_scout_with_a_frame_guess_keeps_every_point_in_the_volume():
    rob, x, u, sight = _case(half=(0.9, 0.9, 0.5))    # about the reach near home only
    qm, _, _ = mp.scout(rob, x, u, sight, PlanRequest(count=80, seed=8))
    assert len(qm) == 10                                 # an eighth of the count
    _independent_checks(rob, x, u, sight, qm, facing=False)


def test_sight_checks_a_point_s_outward_direction_and_one_at_the_origin():
    rob = _robot()
    x = rob.nominal                        # the instrument's frame is the base link's
    q = np.zeros((1, 6))                   # tool0 at (0.89, 0, 1.25), its z along base x
    box = dict(volume_min=(-3, -3, -1), volume_max=(3, 3, 3), max_angle=math.radians(30))
    u = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, -0.05], [0.001, 0.0, 0.0]])
    front = mp.Sight(viewpoint=(2.5, 0.0, 1.25), **box)
    assert mp.visible(rob, x, u, front, q).tolist() == [[True, False, True]]
    behind = mp.Sight(viewpoint=(-2.5, 0.0, 1.25), **box)
    assert mp.visible(rob, x, u, behind, q).tolist() == [[False, True, True]]
    given = mp.Sight(viewpoint=(-2.5, 0.0, 1.25), outward=[[0, 0, 1]] * 3, **box)
    assert mp.visible(rob, x, u, given, q).tolist() == [[False, False, False]]
    small = mp.Sight(volume_min=(0.8, -0.1, 1.2), volume_max=(0.92, 0.1, 1.3),
                     viewpoint=(2.5, 0.0, 1.25), max_angle=math.pi)
    inside, facing = mp.sight_checks(rob, x, u, small, q)
    assert inside.tolist() == [[False, True, True]] and facing.all()
    with pytest.raises(CalibrationError, match="volume_min"):
        mp.Sight((0, 0, 0), (1, -1, 1), (0, 0, 0), 1.0)
