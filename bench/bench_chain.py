"""Bench: position calibration of a UR5-like 6R arm from 1000 poses (a laser
tracker's reflector, 3 rows per pose) with the generic chain
(calibration/chain.py): our solver against scipy.optimize.least_squares and
against FIGAROH (Pinocchio), on the same data.

Problem: the DH model of calibration.chain.dh_model (base, 6 R joints, tool
``b_e, gamma_e``) with the UR5 nominal d1=0.089159, a2=-0.425, a3=-0.39225,
d4=0.10915, d5=0.09465, d6=0.0823, alpha1=pi/2, alpha4=pi/2, alpha5=-pi/2 and
the reflector 0.1 m along the flange's z axis and 0.03 m along its x (b_e,
a6); transmission ratios 1, fixed (the joints are measured directly). The
truth is drawn around the nominal (lengths +-2 mm, angles +-2 mrad, 1 sigma),
the joints uniform in [-pi, pi], the tracker's noise 2e-5 m per coordinate.

Runners (all from the nominal):

* ``ours``: ``solve(model, SolverOptions(fixed=k1..k6))``;
* ``lm``, ``trf``: ``least_squares(method='lm'|'trf')`` on the same residual
  and analytic Jacobian ``-W`` over the parameters ours found identifiable,
  ``fun`` and ``jac`` sharing one ``model.evaluate`` per point (the counters of
  bench_solver.py), ``x_scale='jac'``, ``xtol = ftol = gtol = 1e-12``;
* ``figaroh`` (if installed; ``pip install figaroh``): FIGAROH's geometric
  calibration (``BaseCalibration``, its ``full_params`` model of the same arm
  written as a URDF, position-only markers, scipy ``lm`` on finite
  differences as FIGAROH runs it) on the same joint values and readings.

Timing: the runners are called ``--repeats`` times after a warm-up, interleaved
round by round (bench/_common.py); the best time counts, the median is shown
beside it. ``ratio`` = wall(runner) / wall(ours): > 1 means ours is faster.
``--old-chain REV`` also times the model's evaluation with calibration/chain.py
of git revision REV (the chain before a change), interleaved with today's.

    python bench/bench_chain.py                 # ~1 min with FIGAROH
    python bench/bench_chain.py --poses 200 --repeats 5
    python bench/bench_chain.py --old-chain af559ca
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
from calibration.chain import DHJoint, dh_model  # noqa: E402
from calibration.model import MeasurementModel  # noqa: E402
from calibration.solver import SolverOptions, solve  # noqa: E402

PI = math.pi
# (d, a, alpha) of the UR5's six joints; the reflector adds a6 and b_e.
UR5_DH = ((0.089159, 0.0, PI / 2), (0.0, -0.425, 0.0), (0.0, -0.39225, 0.0),
          (0.10915, 0.0, PI / 2), (0.09465, 0.0, -PI / 2), (0.0823, 0.0, 0.0))
REFLECTOR = (0.03, 0.1)  # along the flange's x (a6) and z (b_e), m
NOISE = 2e-5  # tracker, m per coordinate
SPREAD = {"length": 2e-3, "angle": 2e-3}


def ur5_model():
    joints = [DHJoint("R", d=d, a=a, alpha=al) for d, a, al in UR5_DH]
    joints[-1] = DHJoint("R", d=UR5_DH[-1][0], a=REFLECTOR[0], alpha=UR5_DH[-1][2])
    return dh_model(joints, tool=(REFLECTOR[1], 0.0))


class TrackerPosition(MeasurementModel):
    """The reflector's position in the tracker (= base) frame, 3 rows per pose:
    residual ``p_M - p(Qm, xi)``, observation matrix the translation rows of
    the chain's generalized Jacobian."""

    method = "position (bench)"
    default_damping = 1e-4

    def __init__(self, dh, qm, p_m):
        self.chain, self.qm, self.p_m = dh.chain, np.asarray(qm, float), np.asarray(p_m, float)
        self.names, self.nominal = dh.names, dh.nominal.copy()
        self.x0 = dh.nominal.copy()
        self.n_poses = len(self.qm)
        self.channels = ("position",)  # one tracker, one sigma for x, y and z
        self.row_channel = np.zeros(3 * self.n_poses, dtype=np.intp)

    def evaluate(self, x):
        T, psi = self.chain.jacobian(self.qm, x, position_only=True)
        r = (self.p_m - T[:, :3, 3]).reshape(-1)
        return r, psi.reshape(-1, len(self.names))

    def residual(self, x):
        return (self.p_m - self.chain.fk(self.qm, x)[:, :3, 3]).reshape(-1)


def make_problem(n_poses: int, seed: int):
    """``(Problem, truth)``: the data set of the module doc."""
    dh = ur5_model()
    rng = np.random.default_rng(seed)
    angle = np.array([nm.startswith(("theta", "alpha", "gamma")) or nm.endswith("_off")
                      for nm in dh.names])
    gain = np.array([nm.startswith("k") for nm in dh.names])
    spread = np.where(angle, SPREAD["angle"], SPREAD["length"]) * ~gain
    truth = dh.nominal + rng.normal(size=dh.nominal.size) * spread
    qm = rng.uniform(-PI, PI, (n_poses, 6))
    p_m = dh.chain.fk(qm, truth)[:, :3, 3] + rng.normal(scale=NOISE, size=(n_poses, 3))
    model = TrackerPosition(dh, qm, p_m)
    name = f"UR5-like position ({n_poses} poses, {3 * n_poses} rows)"
    return Problem(name, model.method, True, model, truth, model.residual), dh


GAINS = tuple(f"k{i}" for i in range(1, 7))


def held_out_set(dh, truth, seed, n=500):
    """``(qm, err)``: ``n`` fresh poses and ``err(p)``, the RMS over
    coordinates of predicted reflector positions ``p (n, 3)`` against the
    noise-free truth there."""
    qm = np.random.default_rng([seed, 99]).uniform(-PI, PI, (n, 6))
    p_true = dh.chain.fk(qm, truth)[:, :3, 3]
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
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    threads = {v: os.environ.get(v, "unset") for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    print(f"numpy {np.__version__}, scipy {scipy.__version__}, python {sys.version.split()[0]}; "
          f"seed {args.seed}; BLAS threads {threads}")
    prob, dh = make_problem(args.poses, args.seed)
    model = prob.model
    opts = SolverOptions(fixed=GAINS)
    res = solve(model, opts)
    active = np.array([s.identifiable for s in res.status])
    ident = active.sum()
    qm_h, err = held_out_set(dh, prob.truth, args.seed)

    def held(x):
        return err(dh.chain.fk(qm_h, x)[:, :3, 3])

    print(f"\n=== {prob.name}: {ident} identifiable of {len(res.names)} "
          f"(k1..k6 fixed; not identifiable: "
          f"{', '.join(s.name for s in res.status if not s.identifiable and s.name not in GAINS)})"
          f"\n    ours: {res.message}; sigma {res.sigma['position']:.2e} m (true {NOISE:g}); "
          f"held-out position error RMS {held(res.x):.2e} m (nominal {held(dh.nominal):.2e} m)")
    runners = [("ours", lambda: solve(model, opts), None)]
    for method in ("lm", "trf"):
        c, once = run_scipy(prob, active, None, method, True, "jac")
        sres = once()
        x = c.full(sres.x)
        dxs = float(np.max(np.abs(x - res.x)[active] / res.std[active]))
        runners.append((method, once, (c, sres, dxs)))
    fig = None if args.no_figaroh else figaroh_runner(dh, model, prob.truth)
    timed = [fn for _n, fn, _i in runners]
    x0 = model.x0
    timed.append(lambda: model.evaluate(x0))
    old = None
    if args.old_chain:
        old = old_chain(args.old_chain, dh.chain)
        qm = model.qm
        timed += [lambda: old.jacobian(qm, x0), lambda: dh.chain.jacobian(qm, x0),
                  lambda: old.fk(qm, x0), lambda: dh.chain.fk(qm, x0)]
    times = interleaved_times(timed, args.repeats, warmup=1)
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
        out.append(fig.row(t_ours, args.figaroh_repeats))
    print(table(out, ["runner", "converged (status)", "iter", "evaluations", "best ms",
                      "median ms", "max|x-x_ours|/std", "ratio t/t_ours"]))
    k = len(runners)
    print(f"\n--> {args.poses}-pose 6R position solve, ours: {1e3 * t_ours:.1f} ms "
          f"(median {1e3 * med[0]:.1f}); one model.evaluate {1e3 * best[k]:.2f} ms; ratios "
          + ", ".join(f"{n} {best[i] / t_ours:.2f}" for i, (n, _f, _x) in enumerate(runners)
                      if i) + (f", figaroh {fig.t / t_ours:.1f}" if fig and fig.t else "")
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


def figaroh_runner(dh, model, truth):
    """The FIGAROH runner, or None where figaroh is not installed."""
    try:
        import bench_figaroh
    except ModuleNotFoundError as e:
        if e.name and e.name.split(".")[0] in ("figaroh", "pinocchio"):
            return None
        raise
    return bench_figaroh.FigarohRun(dh, model, truth)


if __name__ == "__main__":
    main()
