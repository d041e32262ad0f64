"""Pose design (calibration/design.py, station/planning/pose_design.py): the D-optimal
choice against exhaustive search and random plans, and the Cramer-Rao
prediction against the scatter of real calibrations on the plan."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from calibration import design as dz
from calibration import simulate
from calibration.errors import CalibrationError
from calibration.methods import MethodData, build
from calibration.robots import get_robot
from calibration.solver import SolverOptions, solve
from station.planning import pose_design as pd
from station.simulation.tracegen import candidate_pool

# the station's devices, averaged over 5 samples (the session's default)
NOISE = {"distance": 1e-5 / np.sqrt(5), "tilt": 1.7e-4 / np.sqrt(5)}


def _info(blocks):
    blocks = np.asarray(blocks, dtype=float)
    scale = np.linalg.norm(blocks.reshape(-1, blocks.shape[2]), axis=0)
    return dz.PoseInformation(tuple(f"p{j}" for j in range(blocks.shape[2])),
                              np.arange(blocks.shape[2]), blocks, scale,
                              tuple(np.array([i]) for i in range(len(blocks))))


def test_d_optimal_matches_exhaustive_search():
    """Exchange is a local search: its D-efficiency ``(det/det_best)^(1/L)`` against
    the exhaustive optimum is at least 0.99, and it finds the optimum itself mostly."""
    rng = np.random.default_rng(3)
    exact = 0
    for trial in range(8):
        info = _info(rng.normal(size=(12, 2, 4)) * rng.uniform(0.1, 10, size=4))
        chosen = dz.d_optimal(info, 4)
        best = max(np.linalg.slogdet(info.matrix(c))[1]
                   for c in itertools.combinations(range(12), 4))
        got = np.linalg.slogdet(info.matrix(chosen))[1]
        assert np.exp((got - best) / 4) >= 0.99, (trial, got, best)
        exact += got >= best - 1e-9 * abs(best)
    assert exact >= 6


def test_d_optimal_keeps_fixed_and_counts():
    info = _info(np.random.default_rng(1).normal(size=(30, 1, 3)))
    chosen = dz.d_optimal(info, 8, fixed=[5, 7])
    assert list(chosen[:2]) == [5, 7] and len(set(chosen)) == 8
    with pytest.raises(CalibrationError, match="pool of only 30"):
        dz.d_optimal(info, 31)


def test_d_optimal_choice_does_not_flip_on_round_off():
    """Issue 40: candidates that tie in exact arithmetic (each pose and its mirror image,
    whose rows differ in sign only; the same pose twice) gain the same; with another
    machine's round-off they differ in the last bits. The choice is the same whatever
    those bits are: a near tie falls to the first candidate (calibration/ties.py)."""
    rng = np.random.default_rng(11)
    flips_without = 0
    for trial in range(20):
        half = rng.normal(size=(15, 2, 5)) * rng.uniform(0.1, 10, size=5)
        blocks = np.concatenate([half, -half, half[:3]])      # mirrors and duplicates
        info = _info(blocks)
        chosen = dz.d_optimal(info, 8).tolist()
        for k in range(5):
            off = blocks * (1 + 4e-16 * rng.standard_normal(blocks.shape))
            assert dz.d_optimal(_info(off), 8).tolist() == chosen, (trial, k)
            # what a plain argmax would do with those bits: the first gain differs
            gains = dz._gains(_info(off).scaled, np.linalg.inv(
                dz.RIDGE * np.eye(5)))
            flips_without += int(np.argmax(gains)) != int(np.argmax(dz._gains(
                info.scaled, np.linalg.inv(dz.RIDGE * np.eye(5)))))
    assert flips_without > 0       # the ties are real: round-off alone moves a plain argmax


def test_cramer_rao_is_the_least_squares_covariance():
    rng = np.random.default_rng(2)
    info = _info(rng.normal(size=(40, 3, 5)))
    A = info.blocks.reshape(-1, 5)
    expect = np.sqrt(np.diag(np.linalg.inv(A.T @ A)))
    np.testing.assert_allclose(dz.cramer_rao(info, np.arange(40)), expect, rtol=1e-10)
    assert np.all(np.isinf(dz.cramer_rao(info, [0])))  # 3 rows cannot identify 5


def test_observability_indices():
    info = _info(np.eye(3)[None].repeat(4, axis=0))  # 4 identical poses, orthonormal rows
    o = dz.observability(info, [0, 1])
    # scaled columns have norm 1/2 over the pool: s = 1/sqrt(2) each
    assert o["O1"] == pytest.approx(np.sqrt(0.5) / np.sqrt(2))
    assert o["O3"] == pytest.approx(np.sqrt(0.5))
    assert o["condition_number"] == pytest.approx(1.0)


def test_twenty_designed_poses_beat_forty_random_distance_tilt():
    """The issue's figure: 20 D-optimal poses of the default box give a smaller
    geometric-mean Cramer-Rao std than 40 random ones, no parameter worse than 2x."""
    robot = get_robot("agebot-sm")
    model, _, _ = candidate_pool("sm-distance-tilt", robot.nominal, 400, seed=1)
    info = dz.pose_information(model, model.x0, NOISE)
    assert len(info.names) == 13
    s_opt = dz.cramer_rao(info, dz.d_optimal(info, 20))
    rng = np.random.default_rng(11)
    gm, worst = [], []
    for _ in range(30):
        s_r = dz.cramer_rao(info, rng.choice(info.size, 40, replace=False))
        gm.append(dz.geometric_mean_std(s_opt) / dz.geometric_mean_std(s_r))
        worst.append(np.max(s_opt / s_r))
    assert np.median(gm) <= 1.0
    assert np.median(worst) <= 2.0


@pytest.mark.parametrize("method", ["sm-self-redundancy", "pm-fk"])
def test_design_for_other_methods(method):
    """Groups stay whole (pairs) and the wrist's design runs on the true wrist."""
    robot = get_robot("agebot-pm" if method.startswith("pm") else "agebot-sm")
    x = robot.true if robot.name == "agebot-pm" else robot.nominal
    model, qm, group = candidate_pool(method, x, 120, seed=4)
    d = pd.design_poses(model, 12, group=group, robot=robot, heldout_qm=qm[:10])
    assert d.design == "optimal" and np.all(np.isfinite(d.std))
    if group is not None:
        assert len(d.fit) == 24 and all(np.sum(group[d.fit] == g) == 2 for g in group[d.fit])
    assert d.heldout["rms"] > 0 and d.heldout["what"] in ("position", "orientation")


def test_target_adds_poses_until_met():
    robot = get_robot("agebot-sm")
    model, qm, _ = candidate_pool("sm-distance-tilt", robot.nominal, 200, seed=5)
    base = pd.design_poses(model, 20, noise=NOISE, robot=robot, heldout_qm=qm[-20:])
    goal = base.heldout["rms"] / 2
    more = pd.design_poses(model, 20, noise=NOISE, robot=robot, heldout_qm=qm[-20:],
                           target=("heldout", goal))
    assert len(more.fit) > 20 and more.heldout["rms"] <= goal
    k = base.names.index("k1")
    more_k1 = pd.design_poses(model, 20, noise=NOISE, target=("k1", base.std[k] * 0.8))
    assert more_k1.std[k] <= base.std[k] * 0.8
    with pytest.raises(CalibrationError, match="not an identifiable parameter"):
        pd.design_poses(model, 20, noise=NOISE, target=("nonsense", 1.0))
    with pytest.raises(CalibrationError, match="even all"):
        pd.design_poses(model, 20, noise=NOISE, target=("k1", 1e-15))


def test_prediction_matches_monte_carlo_scatter():
    """The predicted std of a plan is the scatter of calibrations on it (within 10 %),
    predicted at the model the first calibration gives (as the session re-predicts
    after its first poses; a prediction on a nominal that is 10 % off is off by as much)."""
    robot = get_robot("agebot-sm")
    method = "sm-distance-tilt"
    model, qm, _ = candidate_pool(method, robot.nominal, 330, seed=2)
    plan = pd.design_poses(model, 33, noise=NOISE)
    q, ref = qm[plan.fit], model.reference_qm
    rng = np.random.default_rng(5)
    est = []
    for _ in range(400):
        ch = simulate.measure(method, robot, robot.true, q, reference_qm=ref, noise=NOISE,
                              rng=rng)
        m = build(method, robot, MethodData(q, ch, reference_qm=ref), robot.nominal)
        res = solve(m, SolverOptions(sigma=dict(NOISE)))
        assert res.converged
        est.append(res.x)
    est = np.array(est)
    again = pd.pool_model(method, robot, est[0], q, reference_qm=ref)
    pred = pd.design_poses(again, len(q), design="random", noise=NOISE)
    scatter = est.std(axis=0, ddof=1)
    for name, s in zip(pred.names, pred.std):
        ratio = scatter[list(m.names).index(name)] / s
        assert 0.9 <= ratio <= 1.1, (name, ratio)


def test_design_on_a_robot_file_arm_keeps_its_fixed_parameters():
    """A robot file's arm: the pool's readings come from its own model, the design is
    for the identifiable set without the file's ``fixed`` (27 for the UR5-like arm's
    tracker positions, Hayati form), and designed poses beat as many random ones."""
    from pathlib import Path

    from drivers.robot_file import load_robot_file
    from station.simulation import tracegen_serial as ts

    root = Path(__file__).resolve().parents[2]
    robot = get_robot(load_robot_file(root / "fixtures/robots/ur5-like-hayati.toml"))
    _, _, poses = ts.generate(robot, "sm-position", robot.nominal, count=300, seed=3)
    qm = np.array([p["qm"] for p in poses])
    model = pd.pool_model("sm-position", robot, robot.nominal, qm)
    info = dz.pose_information(model, model.x0, pd.DEFAULT_NOISE)
    assert len(info.names) == 27 and not set(info.names) & set(robot.fixed)
    s_opt = dz.cramer_rao(info, dz.d_optimal(info, 45))
    rng = np.random.default_rng(2)
    ratio = np.median([dz.geometric_mean_std(s_opt) / dz.geometric_mean_std(
        dz.cramer_rao(info, rng.choice(info.size, 45, replace=False))) for _ in range(15)])
    assert ratio < 0.95


def test_the_travel_order_is_the_greedy_nearest_neighbour():
    """``calibration.planning.order_for_travel`` visits, from the start (or the first
    pose), the nearest pose not yet visited in scaled actuator space (max norm), the
    first of equals (but for round-off: calibration/ties.py) in index order: against that
    rule written out pose by pose, with ties (rounded poses) and without, from a start and
    from the first pose; and the same order when every value is off by round-off."""
    from calibration.planning import order_for_travel

    rng = np.random.default_rng(7)
    for t in range(60):
        n = int(rng.integers(1, 40))
        qm = rng.normal(size=(n, 4)) * [0.1, 1.0, 2.0, 3.0]
        if t % 3 == 0:
            qm = np.round(qm, 1)  # equal distances
        start = None if t % 2 else rng.normal(size=4)
        s = np.ptp(qm, axis=0)
        s = np.where(s > 0, s, 1.0)
        cur = qm[0] / s if start is None else start / s
        left, expect = list(range(n)), []
        while left:
            d = [float(np.max(np.abs(qm[i] / s - cur))) for i in left]
            best = min(d)
            i = left.pop(next(k for k, x in enumerate(d) if x - best <= 1e-9 * max(1.0, best)))
            expect.append(i)
            cur = qm[i] / s
        got = order_for_travel(qm, start)
        assert got.tolist() == expect, t
        assert sorted(got.tolist()) == list(range(n))
        # another machine's round-off (a few units in the last place): the same order
        off = qm * (1 + 4e-16 * rng.standard_normal(qm.shape))
        assert order_for_travel(off, start, scale=s).tolist() == expect, t


@pytest.mark.parametrize("rows", [1, 2, 3])
def test_the_d_gains_are_the_determinants_they_stand_for(rows, monkeypatch):
    """``_gains`` writes out ``log det(I + B M^-1 B^T)`` for blocks of one and two rows:
    against ``slogdet`` of the matrix itself, a singular or indefinite one included
    (-inf), and the exchange's choice is the same."""
    rng = np.random.default_rng(rows)
    for trial in range(20):
        B = rng.normal(size=(50, rows, 5))
        A = rng.normal(size=(12, 5))
        Minv = np.linalg.inv(A.T @ A)
        if trial == 0:
            Minv = -Minv                       # log det of an indefinite I + S: -inf
        S = np.eye(rows) + B @ Minv @ B.transpose(0, 2, 1)
        sign, ld = np.linalg.slogdet(S)
        expect = np.where(sign > 0, ld, -np.inf)
        got = dz._gains(B, Minv)
        assert np.array_equal(np.isinf(got), np.isinf(expect)), trial
        fin = np.isfinite(expect)
        assert np.allclose(got[fin], expect[fin], rtol=1e-12, atol=1e-12), trial
    info = _info(rng.normal(size=(60, rows, 5)) * rng.uniform(0.1, 10, size=5))
    chosen = dz.d_optimal(info, 8)

    def by_slogdet(B, Minv):
        sign, ld = np.linalg.slogdet(np.eye(B.shape[1]) + B @ Minv @ B.transpose(0, 2, 1))
        return np.where(sign > 0, ld, -np.inf)

    monkeypatch.setattr(dz, "_gains", by_slogdet)
    assert dz.d_optimal(info, 8).tolist() == chosen.tolist()


def test_batched_sampling_draws_the_poses_one_at_a_time_would():
    """``sample_poses`` asks a robot with ``ik_many`` for a batch of draws at once: the same
    targets, actuator values to rounding, draw count and generator state after as the IK
    of one pose at a time, with an ``accept`` that refuses some, an elbow asked for, and
    a box partly out of reach; ``ik_many`` refuses exactly the poses ``ik`` does."""
    from calibration import planning
    from calibration.errors import UnreachablePose
    import calibration.planning as cp

    robot = get_robot("agebot-sm")
    xi = robot.nominal
    box = planning.box_array(robot, planning.SM_BOX_7_1, np.r_[robot.base_offset(xi), 0.0])
    for t in range(12):
        bounds = planning.scale_box(box, (0.3, 1.0, 2.5)[t % 3])
        accept = (lambda X, q: q[0] < 0.0) if t % 2 else None
        opts = {"elbow": -1} if t % 4 == 3 else {}
        a_rng, b_rng = np.random.default_rng(t), np.random.default_rng(t)
        a = cp._sample_one_by_one(robot, xi, bounds, 25, a_rng, 5000, opts, accept)
        b = cp._sample_batched(robot, xi, bounds, 25, b_rng, 5000, opts, accept)
        assert a[2] == b[2] and np.array_equal(np.array(a[0]), np.array(b[0])), t
        assert np.allclose(np.array(a[1]), np.array(b[1]), rtol=1e-12, atol=1e-9), t
        assert a_rng.random() == b_rng.random(), t
    X = np.random.default_rng(5).uniform(*planning.scale_box(box, 2.5).T, size=(400, 4))
    qm, ok = robot.ik_many(X, xi)
    for i in range(len(X)):
        try:
            q = robot.ik(X[i], xi)
        except UnreachablePose:
            assert not ok[i] and np.all(np.isnan(qm[i])), i
            continue
        assert ok[i] and np.allclose(qm[i], q, rtol=1e-12, atol=1e-9), i
    assert 0 < ok.sum() < len(X)
    with pytest.raises(CalibrationError, match="reachable after 40 draws"):
        planning.sample_poses(robot, xi, planning.scale_box(box, 0.0) + 5.0, 3,
                              np.random.default_rng(0), max_draws=40)
