"""Bench: position calibration of a UR5-like 6R arm from 1000 poses (a laser
tracker's reflector, 3 rows per pose) with the generic chain
(calibration/chain.py): our solver against scipy.optimize.least_squares and
against FIGAROH (Pinocchio), on the same data.

Problem: the robot file fixtures/robots/ur5-like-dh.toml (the station's
generic serial model, calibration/robots/serial.py): the UR5 DH nominal
d1=0.089159, a2=-0.425, a3=-0.39225, d4=0.10915, d5=0.09465, d6=0.0823,
alpha1=pi/2, alpha4=pi/2, alpha5=-pi/2, in the frame of a laser tracker 1.4 m
away (base), the reflector on an angled tool 5 cm out and 3 cm off the flange
axis; transmission ratios 1, fixed (the file's ``fixed``). The method is the
station's ``sm-position`` (3 rows per pose). The truth is drawn around the
nominal (lengths +-2 mm, angles +-2 mrad, 1 sigma), the joints uniform within
the file's limits, the tracker's noise 2e-5 m per coordinate, given to the
solver as known (as a trace's ``sigma``), so that ours and scipy minimize the
same sum of squares.

Runners (all from the nominal):

* ``ours``: ``solve(model, SolverOptions(fixed=the file's, sigma=...))``;
* ``lm``, ``trf``: ``least_squares(method='lm'|'trf')`` on the same residual
  and analytic Jacobian ``-W`` over the parameters ours found identifiable,
  ``fun`` and ``jac`` sharing one ``model.evaluate`` per point (the counters of
  bench_solver.py), ``x_scale='jac'``, ``xtol = ftol = gtol = 1e-12``;
* ``figaroh`` (if installed; ``pip install figaroh``): FIGAROH's geometric
  calibration (``BaseCalibration``, its ``full_params`` model of the same arm
  written as a URDF by the station's own export, position-only markers, scipy ``lm`` on finite
  differences as FIGAROH runs it) on the same joint values and readings.

Timing: the runners are called ``--repeats`` times after a warm-up, interleaved
round by round (bench/_common.py); the best time counts, the median is shown
beside it. ``ratio`` = wall(runner) / wall(ours): > 1 means ours is faster.
``--old-chain REV`` also times the model's evaluation with calibration/chain.py
of git revision REV (the chain before a change), interleaved with today's.

    python bench/bench_chain.py                 # ~1 min with FIGAROH
    python bench/bench_chain.py --poses 200 --repeats 5
    python bench/bench_chain.py --old-chain af559ca
    python bench/bench_chain.py --robot-file fixtures/robots/ur5-like-hayati.toml
"""
from __future__ import annotations

import os
import sys

if __name__ == "__main__":  # single-threaded BLAS, read when numpy loads
    for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import time  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import scipy  # noqa: E402

from _common import ROOT, Problem, interleaved_times, table  # noqa: E402
from bench_solver import run_scipy  # noqa: E402
from calibration.methods import MethodData, build  # noqa: E402
from calibration.robots import get_robot  # noqa: E402
from calibration.solver import SolverOptions, solve  # noqa: E402
from drivers.robot_file import load_robot_file  # noqa: E402

PI = math.pi
# Hayati's form: the same 6R arm FIGAROH's joint placements describe without DH's
# ill-defined d on parallel axes (the DH file fits another model: d2, d3, d4 slide)
ROBOT_FILE = os.path.join(ROOT, "fixtures", "robots", "ur5-like-hayati.toml")
NOISE = 2e-5  # tracker, m per coordinate
SPREAD = {"length": 2e-3, "angle": 2e-3}


def make_problem(n_poses: int, seed: int, robot_file: str = ROBOT_FILE):
    """``(Problem, robot)``: the data set of the module doc."""
    robot = get_robot(load_robot_file(robot_file))
    rng = np.random.default_rng(seed)
    names = robot.param_names
    angle = np.array([nm.split("_")[-1].rstrip("0123456789") in ("theta", "alpha", "beta",
                                                                 "gamma", "off")
                      for nm in names])
    free = np.array([nm not in robot.fixed for nm in names])
    spread = np.where(angle, SPREAD["angle"], SPREAD["length"]) * free
    truth = robot.nominal + rng.normal(size=len(names)) * spread
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    qm = rng.uniform(lo, hi, (n_poses, robot.n_actuators))
    p_m = robot.frames(qm, truth)[:, :3, 3] + rng.normal(scale=NOISE, size=(n_poses, 3))
    model = build("sm-position", robot, MethodData(qm, {"position": p_m}), robot.nominal)

    def residual(x):  # r by forward kinematics only
        return (p_m - robot.frames(qm, x)[:, :3, 3]).reshape(-1)

    name = f"{robot.name} sm-position ({n_poses} poses, {3 * n_poses} rows)"
    return Problem(name, model.method, True, model, truth, residual), robot


def held_out_set(robot, truth, seed, n=500):
    """``(qm, err)``: ``n`` fresh poses and ``err(p)``, the RMS over
    coordinates of predicted reflector positions ``p (n, 3)`` against the
    noise-free truth there."""
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    qm = np.random.default_rng([seed, 99]).uniform(lo, hi, (n, robot.n_actuators))
    p_true = robot.frames(qm, truth)[:, :3, 3]
    return qm, lambda p: float(np.sqrt(np.mean((p - p_true) ** 2)))


def old_chain(rev: str, chain):
    """``chain`` rebuilt with calibration/chain.py of git revision ``rev``."""
    src = subprocess.run(["git", "-C", ROOT, "show", f"{rev}:calibration/chain.py"],
                         capture_output=True, text=True, check=True).stdout
    spec = importlib.util.spec_from_loader(f"chain_{rev}", loader=None)
    mod = sys.modules[spec.name] = importlib.util.module_from_spec(spec)  # dataclasses need it
    exec(compile(src, f"{rev}:calibration/chain.py", "exec"), mod.__dict__)  # noqa: S102
    factors = tuple(mod.Factor(f.kind, f.const, f.terms, f.joint) for f in chain.factors)
    return mod.Chain(factors, chain.n_params, chain.offset_idx, chain.gain_idx)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--poses", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=15, help="timed rounds (best counts)")
    ap.add_argument("--figaroh-repeats", type=int, default=3)
    ap.add_argument("--old-chain", metavar="REV",
                    help="also time the evaluation with calibration/chain.py of this git revision")
    ap.add_argument("--no-figaroh", action="store_true")
    ap.add_argument("--robot-file", default=ROBOT_FILE,
                    help="another 6R arm, e.g. fixtures/robots/ur5-like-hayati.toml")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    threads = {v: os.environ.get(v, "unset") for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    print(f"numpy {np.__version__}, scipy {scipy.__version__}, python {sys.version.split()[0]}; "
          f"seed {args.seed}; BLAS threads {threads}")
    prob, robot = make_problem(args.poses, args.seed, args.robot_file)
    model = prob.model
    opts = SolverOptions(fixed=robot.fixed, sigma=dict.fromkeys(model.channels, NOISE))
    res = solve(model, opts)
    active = np.array([s.identifiable for s in res.status])
    ident = active.sum()
    qm_h, err = held_out_set(robot, prob.truth, args.seed)

    def held(x):
        return err(robot.frames(qm_h, x)[:, :3, 3])

    print(f"\n=== {prob.name}: {ident} identifiable of {len(res.names)} "
          f"({', '.join(robot.fixed)} fixed; not identifiable: "
          f"{', '.join(s.name for s in res.status if not s.identifiable and s.name not in robot.fixed)})"
          f"\n    ours: {res.message}; residual RMS {res.residual_rms['x']:.2e} m (noise {NOISE:g}); "
          f"held-out position error RMS {held(res.x):.2e} m (nominal {held(robot.nominal):.2e} m)")
    runners = [("ours", lambda: solve(model, opts), None)]
    for method in ("lm", "trf"):
        c, once = run_scipy(prob, active, None, method, True, "jac")
        sres = once()
        x = c.full(sres.x)
        dxs = float(np.max(np.abs(x - res.x)[active] / res.std[active]))
        runners.append((method, once, (c, sres, dxs)))
    fig = None if args.no_figaroh else figaroh_runner(robot, model, prob.truth)
    timed = [fn for _n, fn, _i in runners]
    n_fig = None
    if fig is not None:      # FIGAROH in the same interleave, after the same warm-up
        try:
            fig.prepare(args.figaroh_repeats + 1)
            timed.append(fig.timed_solve)
            n_fig = len(timed) - 1
        except Exception as e:  # noqa: BLE001 - the table reports FIGAROH's failure
            fig.error = f"{type(e).__name__}: {e}"
    x0 = model.x0
    timed.append(lambda: model.evaluate(x0))
    old = None
    if args.old_chain:
        old = old_chain(args.old_chain, robot.chain)
        qm = model.qm
        timed += [lambda: old.jacobian(qm, x0), lambda: robot.chain.jacobian(qm, x0),
                  lambda: old.fk(qm, x0), lambda: robot.chain.fk(qm, x0)]
    times = interleaved_times(timed, args.repeats, warmup=1) if n_fig is None else \
        _interleave_with_figaroh(timed, n_fig, args.repeats, args.figaroh_repeats)
    if n_fig is not None:
        fig.set_times(times.pop(n_fig))
    best = [min(t) for t in times]
    med = [statistics.median(t) for t in times]
    t_ours = best[0]
    out = [("ours", res.converged, res.iterations, res.nfev, f"{1e3 * best[0]:.1f}",
            f"{1e3 * med[0]:.1f}", "0", "1.00")]
    for i, (name, _fn, (c, sres, dxs)) in enumerate(runners[1:], start=1):
        out.append((name, f"{sres.success} ({sres.status})", sres.njev, c.model_calls,
                    f"{1e3 * best[i]:.1f}", f"{1e3 * med[i]:.1f}", f"{dxs:.1e}",
                    f"{best[i] / t_ours:.2f}"))
    if fig is not None:
        out.append(fig.row(t_ours, res.residual_rms["x"] and
                           float(np.sqrt(np.mean(np.asarray(res.residual) ** 2)))))
    print(table(out, ["runner", "converged (status)", "iter", "evaluations", "best ms",
                      "median ms", "max|x-x_ours|/std", "ratio t/t_ours"]))
    k = len(runners)
    print(f"\n--> {args.poses}-pose 6R position solve, ours: {1e3 * t_ours:.1f} ms "
          f"(median {1e3 * med[0]:.1f}); one model.evaluate {1e3 * best[k]:.2f} ms; ratios "
          + ", ".join(f"{n} {best[i] / t_ours:.2f}" for i, (n, _f, _x) in enumerate(runners)
                      if i) + (f", figaroh {fig.t / t_ours:.1f}" if fig and fig.t and fig.reached(
                          float(np.sqrt(np.mean(np.asarray(res.residual) ** 2)))) else
                          ", figaroh not solved (see its row)" if fig else "")
          + " (> 1: ours faster)")
    if fig is None and not args.no_figaroh:
        print("figaroh not installed (pip install figaroh): FIGAROH not compared")
    elif fig is not None:
        print(fig.summary(None if fig.error else err(fig.held_out(qm_h))))
    if old is not None:
        jo, jn, fo, fn = best[k + 1:k + 5]
        print(f"--> evaluation, calibration/chain.py {args.old_chain} vs now, {args.poses} poses: "
              f"jacobian {1e3 * jo:.2f} -> {1e3 * jn:.2f} ms ({jo / jn:.1f}x), "
              f"fk {1e3 * fo:.2f} -> {1e3 * fn:.2f} ms ({fo / fn:.1f}x)")
    print(f"\nbench wall time {time.perf_counter() - t_start:.1f} s")


def _interleave_with_figaroh(fns, k, repeats, fig_repeats):
    """:func:`interleaved_times` where function ``k`` (FIGAROH, seconds a call) runs
    in the first ``fig_repeats`` rounds only (and the warm-up)."""
    import time as _t

    for fn in fns:
        fn()
    times = [[] for _ in fns]
    for rnd in range(repeats):
        for i, fn in enumerate(fns):
            if i == k and rnd >= fig_repeats:
                continue
            t = _t.perf_counter()
            fn()
            times[i].append(_t.perf_counter() - t)
    return times


def figaroh_runner(robot, model, truth):
    """The FIGAROH runner, or None where figaroh is not installed."""
    try:
        import bench_figaroh
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in ("figaroh", "pinocchio"):
            return None
        raise
    return bench_figaroh.FigarohRun(robot, model, truth)


if __name__ == "__main__":
    main()
