"""Benchmark: the PM solve (pm-fk, alpha+beta) on the station's solver against
scipy.optimize.least_squares ('lm', 'trf') on the same residuals and Jacobian
from the same start (the robust start), noise-free and noisy.

    python bench/bench_pm.py [poses] [noise_rad]
"""
from __future__ import annotations

import sys
import time

import numpy as np
from scipy.optimize import least_squares

from calibration.methods import MethodData, build
from calibration.planning import PM_BOX, box_array, sample_poses
from calibration.robots.agebot_pm import NOMINAL, TRUE, AgebotPM
from calibration.solver import solve


def timed(f, repeat=1):
    t = time.perf_counter()
    for _ in range(repeat):
        out = f()
    return out, (time.perf_counter() - t) / repeat


def main(m: int = 20, noise: float = 0.0, seed: int = 1) -> None:
    robot = AgebotPM()
    rng = np.random.default_rng(seed)
    plan = sample_poses(robot, TRUE, box_array(robot, PM_BOX), m, rng)
    X = plan.targets + noise * rng.normal(size=plan.targets.shape)
    data = MethodData(plan.qm, {"orientation": X[:, :2]}, components=("alpha", "beta"))

    model, t_build = timed(lambda: build("pm-fk", robot, data, NOMINAL))
    x0 = model.x0.copy()
    # the true robot's member of the equivalence family with the nominal q3_off, k3
    sc = NOMINAL[9] / TRUE[9]
    ref = TRUE * sc
    ref[[3, 4, 5, 6]] += NOMINAL[6] - sc * TRUE[6]
    print(f"pm-fk alpha,beta: {m} poses, noise {noise:g} rad, start from the report's nominal")
    st = model.start.result
    print(f"  robust start (joint-space fit, {st.n_rows} rows x {len(st.names)} unknowns): "
          f"{st.iterations} it, {st.nfev} evaluations, {t_build * 1e3:.1f} ms")

    Xs = robot.fk(plan.qm, x0, guess=model.start.X)
    _, t_fk = timed(lambda: robot.fk(plan.qm, x0, guess=Xs), 50)
    _, t_ev = timed(lambda: model.evaluate(x0), 50)
    print(f"  FK of all poses (warm start): {t_fk * 1e3:.3f} ms = {t_fk / m * 1e6:.1f} us/pose; "
          f"one evaluation (FK + Psi^PKU): {t_ev * 1e3:.3f} ms")

    res, t_solve = timed(lambda: solve(model))
    cost = lambda r: 0.5 * float(r @ r)
    r_final = model.evaluate(res.x)[0]
    print(f"  station solver: {res.iterations} it, nfev {res.nfev}, {t_solve * 1e3:.1f} ms, "
          f"cost {cost(r_final):.3e}, {res.message}")

    free = np.array([s.identifiable for s in res.status])  # q3_off, k3 fixed (eqs. 112-113)

    def full(z):
        x = x0.copy()
        x[free] = z
        return x

    def fun(z):
        return -model.evaluate(full(z))[0]  # predicted - measured

    def jac(z):
        return model.evaluate(full(z))[1][:, free]

    rows = [("station Algorithm 2", res.iterations, res.nfev, t_solve, cost(r_final),
             np.abs(res.x - ref).max())]
    for method in ("lm", "trf"):
        model.fk.last = model.start.X.copy()  # the same FK start as the solver had
        out, t = timed(lambda: least_squares(fun, x0[free], jac=jac, method=method,
                                             x_scale="jac", xtol=1e-15, ftol=1e-15,
                                             gtol=1e-15, max_nfev=2000))
        rows.append((f"scipy least_squares {method}", np.nan, out.nfev + out.njev, t,
                     float(out.cost), np.abs(full(out.x) - ref).max()))
    t0 = rows[0][3]
    print(f"  {'solver':28s} {'iter':>5s} {'evals':>6s} {'time ms':>9s} {'cost':>11s} "
          f"{'max|x-ref|':>12s} {'time ratio':>10s}")
    for name, it, nfev, t, c, err in rows:
        its = "-" if np.isnan(it) else f"{int(it)}"
        print(f"  {name:28s} {its:>5s} {nfev:6d} {t * 1e3:9.1f} {c:11.3e} {err:12.2e} "
              f"{t / t0:10.2f}")
    print("  (scipy counts nfev + njev; each station evaluation gives r and W together;\n"
          "   ref = the true robot rescaled to the nominal q3_off, k3, eqs. 112-113)")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]) if args else 20, float(args[1]) if len(args) > 1 else 0.0)
    if not args:
        print()
        main(20, 1e-4)
