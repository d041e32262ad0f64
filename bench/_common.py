"""Shared pieces of the benches: reproducible problems, timing, table output.

Nothing here is imported by the package; the benches run from the repository
root (``python bench/bench_solver.py``).
"""
from __future__ import annotations

import os
import statistics
import sys
import time
from dataclasses import dataclass

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from calibration import planning, simulate  # noqa: E402
from calibration.methods.sm_distance import Distance  # noqa: E402
from calibration.methods.sm_distance_tilt import DistanceTilt, reframe_nominal  # noqa: E402
from calibration.methods.sm_full_pose import FullPose  # noqa: E402
from calibration.robots import get_robot  # noqa: E402
from calibration.robots.agebot_sm import wrap  # noqa: E402

# Reading noise of the noisy variants (std of one reading).
NOISE = {
    "sm-full-pose": {"pose": np.array([1e-4, 1e-4, 1e-4, 1e-3])},  # m, m, m, rad
    "sm-distance": {"distance": 1e-4},  # m
    "sm-distance-tilt": {"distance": 1e-4, "tilt": 1e-3},  # m, rad
}
METHODS = tuple(NOISE)


@dataclass
class Problem:
    """One calibration problem: the model, the truth (in the model's frame) and
    ``residual(x)``: the model's residual ``r(x)`` computed by forward
    kinematics only (no observation matrix), identical to
    ``model.evaluate(x)[0]`` (checked at construction). Finite-difference
    runners use it so that they do not pay for a Jacobian they throw away."""

    name: str
    method: str
    noisy: bool
    model: object
    truth: np.ndarray
    residual: object
    options: object = None  # the SolverOptions ours runs with (None: the defaults)


def _fk_residual(method, robot, model):
    """``r(x)`` of ``model`` by ``robot.fk`` only (same formula as the method)."""
    qm = model.qm
    if method == "sm-full-pose":
        X_m = model.X_m

        def res(x):
            r = X_m - robot.fk(qm, x)
            r[:, 3] = wrap(r[:, 3])
            return r.reshape(-1)
    elif method == "sm-distance":
        assert model.residual == "plain"
        ref_qm, D_m = model.reference_qm, model.D_m

        def res(x):
            X = robot.fk(np.vstack([qm, ref_qm]), x)
            return D_m - np.linalg.norm(X[:-1, :3] - X[-1, :3], axis=1)
    elif method == "sm-distance-tilt":
        assert model.residual == "plain"
        D_m, phi_m = model.D_m, model.phi_m

        def res(x):
            X = robot.fk(qm, x)
            rd = D_m - np.linalg.norm(X[:, :3], axis=1)
            return np.column_stack([rd, wrap(phi_m - X[:, 3])]).reshape(-1)
    else:  # pragma: no cover
        raise ValueError(method)
    return res


def _checked_fk_residual(method, robot, model, truth):
    """:func:`_fk_residual`, checked equal to ``model.evaluate(x)[0]`` at the start and
    at the truth."""
    res = _fk_residual(method, robot, model)
    for x in (model.x0, truth):
        assert np.allclose(res(x), model.evaluate(x)[0], rtol=0, atol=1e-13), \
            "fk residual mismatch"
    return res


def make_problems(seed: int = 1, methods=METHODS, variants=("noise-free", "noisy"),
                  poses: int | None = None):
    """The bench problems: per method the same poses (same seed), read without
    noise and with the reading noise of :data:`NOISE`. A method's poses and
    readings depend on the seed and the method only (its place in
    :data:`METHODS`), not on which other methods are asked for or in what order.
    ``poses``: that many poses for every method instead of the report's
    (17, 45, 33)."""
    sm = get_robot("agebot-sm")
    T, N = sm.true, sm.nominal
    off = np.r_[sm.base_offset(T), 0.0]
    out = []
    for method in methods:
        if method not in METHODS:
            raise ValueError(f"unknown bench method {method!r}")
        mi = METHODS.index(method)
        rng = np.random.default_rng([seed, mi])
        if method == "sm-full-pose":  # report 7.1
            plan = planning.sample_poses(sm, N, planning.box_array(sm, planning.SM_BOX_7_1, off),
                                         poses or 17, rng)
            ref, truth = None, T.copy()
            build = lambda meas: FullPose(sm, plan.qm, meas, N)  # noqa: E731
        elif method == "sm-distance":  # report 7.2, plain residual
            ref = sm.ik(np.array([1.0, 1.0, 0.0, 0.2]) + off, T)
            plan = planning.sample_poses(sm, N, planning.box_array(sm, planning.SM_BOX_7_1, off),
                                         poses or 45, rng)
            truth = T.copy()
            build = lambda meas: Distance(sm, plan.qm, meas, N, reference_qm=ref)  # noqa: E731
        elif method == "sm-distance-tilt":  # report 7.5, re-framed nominal
            ref = sm.ik(np.array([0.5, 1.0, 0.8, 0.0]), T)
            x0 = DistanceTilt(sm, np.zeros((1, 4)), {"distance": [1.0], "tilt": [0.0]}, N,
                              reference_qm=ref).x0
            plan = planning.sample_poses(sm, x0, planning.box_array(sm, planning.SM_BOX_7_5),
                                         poses or 33, rng, ik_options={"elbow": -1})
            truth = reframe_nominal(sm, T, ref)
            build = lambda meas: DistanceTilt(sm, plan.qm, meas, N, reference_qm=ref)  # noqa: E731
        else:
            raise ValueError(f"unknown bench method {method!r}")
        for variant in variants:
            noisy = variant == "noisy"
            meas = simulate.measure(method, sm, T, plan.qm, reference_qm=ref,
                                    noise=NOISE[method] if noisy else None,
                                    rng=np.random.default_rng([seed, mi, 7]))
            model = build(meas)
            res = _checked_fk_residual(method, sm, model, truth)
            out.append(Problem(f"{method} {variant} ({model.n_poses} poses, "
                               f"{len(model.row_channel)} rows)",
                               method, noisy, model, truth, res))
    return out


AGEBOT_FILE = os.path.join(ROOT, "fixtures", "robots", "agebot-sm.toml")


def agebot_file_vector(robot, x):
    """The builtin AGEBOT serial arm's parameters ``x`` (q_off, k, theta0, a0,
    L2-L4) as those of its robot file ``robot`` (fixtures/robots/agebot-sm.toml:
    the same arm with the generic model's 32 parameters, the others at the file's
    nominal): theta0 and a0 become the base's ``base_a`` and ``a1``."""
    b = dict(zip(get_robot("agebot-sm").param_names, x))
    v = dict(zip(robot.param_names, robot.nominal))
    v.update({nm: b[nm] for nm in b if nm in v})     # q_off, k
    v.update(a2=b["L2"], a3=b["L3"], a4=b["L4"], base_a=b["a0"] * np.cos(b["theta0"]),
             a1=b["a0"] * np.sin(b["theta0"]))
    return np.array([v[nm] for nm in robot.param_names])


def make_robot_file_problems(seed: int = 1, variants=("noise-free", "noisy"),
                             poses: int | None = None):
    """sm-distance on the AGEBOT arm written as a robot file (the generic serial
    model a user's arm gets, 32 parameters, 19 of them fixed by the file): the
    poses, reference and readings of :func:`make_problems`' sm-distance problems
    (same seed), the truth and nominal mapped by :func:`agebot_file_vector`.
    Ours runs as the station runs a trace that states its sensors' noise: with
    the file's ``fixed`` and the draw-wire's sigma (one weight for every row:
    scipy's plain problem has the same minimum); scipy moves the parameters ours
    calibrates, as for the other problems."""
    from calibration.methods import MethodData, build
    from calibration.solver import SolverOptions
    from drivers.robot_file import load_robot_file

    robot = get_robot(load_robot_file(AGEBOT_FILE))
    sm = get_robot("agebot-sm")
    out = []
    for prob in make_problems(seed, ("sm-distance",), variants, poses):
        m = prob.model
        truth = agebot_file_vector(robot, sm.true)
        data = MethodData(m.qm, {"distance": m.D_m}, reference_qm=m.reference_qm)
        model = build("sm-distance", robot, data, agebot_file_vector(robot, sm.nominal))
        res = _checked_fk_residual("sm-distance", robot, model, truth)
        out.append(Problem(f"robot file {prob.name}", "sm-distance", prob.noisy, model, truth,
                           res, SolverOptions(fixed=robot.fixed, sigma=NOISE["sm-distance"])))
    return out


FIXTURE_TRACE = os.path.join(ROOT, "fixtures", "traces", "sm-distance.jsonl")


def make_fixture_problem():
    """sm-distance on AGEBOT's robot file over the fixture trace's poses, reference and
    readings (``fixtures/traces/sm-distance.jsonl``: 45 poses, noise 1e-4 m stated, made
    with the builtin arm's truth), from the trace's nominal, run as the station runs
    it (the file's ``fixed``, the trace's sigma): a fit that swings, where the damping
    decides the path (``docs/methods.md``, step acceptance)."""
    from calibration.methods import MethodData, build
    from calibration.solver import SolverOptions
    from drivers.robot_file import load_robot_file
    from station.recording.trace import read_trace

    trace = read_trace(FIXTURE_TRACE)
    robot = get_robot(load_robot_file(AGEBOT_FILE))
    sm = get_robot("agebot-sm")
    poses = trace.fit_poses
    qm = np.array([p["qm"] for p in poses], dtype=float)
    D_m = np.array([p["distance"] for p in poses], dtype=float)
    ref_qm = np.asarray(trace.reference["qm"], dtype=float)
    nominal = np.array([trace.header["nominal"][nm] for nm in sm.param_names])
    data = MethodData(qm, {"distance": D_m}, reference_qm=ref_qm)
    model = build("sm-distance", robot, data, agebot_file_vector(robot, nominal))
    truth = agebot_file_vector(robot, sm.true)
    res = _checked_fk_residual("sm-distance", robot, model, truth)
    return Problem(f"robot file sm-distance fixture trace ({model.n_poses} poses, "
                   f"{len(model.row_channel)} rows)", "sm-distance", True, model, truth, res,
                   SolverOptions(fixed=robot.fixed, sigma=dict(trace.header["sigma"])))


def median_time(fn, repeats: int, warmup: int = 1):
    """``(median seconds, last return value)`` of ``fn()`` over ``repeats`` calls."""
    for _ in range(warmup):
        val = fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        val = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), val


def interleaved_times(fns, repeats: int, warmup: int = 1) -> list[list[float]]:
    """Seconds of each of ``fns`` in each of ``repeats`` rounds; each round calls
    every function once, in turn (interleaved, so that a burst of load on the
    machine affects all of them alike)."""
    for _ in range(warmup):
        for fn in fns:
            fn()
    times = [[] for _ in fns]
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            times[i].append(time.perf_counter() - t)
    return times



def table(rows, headers, aligns=None) -> str:
    """Plain-text table (``aligns``: '<' or '>' per column)."""
    cells = [[str(c) for c in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h)
              for i, h in enumerate(headers)]
    aligns = aligns or ["<"] + [">"] * (len(headers) - 1)
    fmt = lambda r: "  ".join(f"{c:{a}{w}}" for c, a, w in zip(r, aligns, widths))  # noqa: E731
    lines = [fmt(headers), "  ".join("-" * w for w in widths)]
    lines += [fmt(r) for r in cells]
    return "\n".join(lines)
