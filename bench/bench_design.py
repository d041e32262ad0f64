"""Pose design: D-optimal poses against random ones, for every method.

For each method a pool of candidates is planned in the report's workspace box on
the planning model (the nominal arm; the true wrist, as the trace generator
plans it), and the predicted (Cramer-Rao) std of every identifiable parameter is
compared: ``n`` D-optimal poses against ``2n`` random ones (the median over
random draws). Prints the ratio of geometric means (< 1: the designed plan with
half the poses is better) and the worst single parameter ratio, with the
observability indices O1 and O3 (Sun and Hollerbach) of both plans.

    python bench/bench_design.py [--n 20] [--pool 400] [--draws 50] [--methods M,...]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from calibration import design as dz  # noqa: E402
from calibration.methods import METHODS  # noqa: E402
from calibration.robots import BUILTIN, get_robot  # noqa: E402
from station.pose_design import DEFAULT_NOISE  # noqa: E402
from station.tracegen import candidate_pool  # noqa: E402


def compare(method: str, n: int, pool: int, draws: int, seed: int = 1) -> dict:
    robot = get_robot(BUILTIN[METHODS[method].kind])
    x_plan = robot.nominal if robot.name == "agebot-sm" else robot.true
    model, _, group = candidate_pool(method, x_plan, pool, seed=seed)
    info = dz.pose_information(model, model.x0, DEFAULT_NOISE, group=group)
    t0 = time.perf_counter()
    chosen = dz.d_optimal(info, n)
    t_design = time.perf_counter() - t0
    s_opt = dz.cramer_rao(info, chosen)
    rng = np.random.default_rng(seed)
    gm, worst, o_rand = [], [], []
    for _ in range(draws):
        r = rng.choice(info.size, size=min(2 * n, info.size), replace=False)
        s_r = dz.cramer_rao(info, r)
        gm.append(dz.geometric_mean_std(s_opt) / dz.geometric_mean_std(s_r))
        worst.append(float(np.max(s_opt / s_r)))
        o_rand.append(dz.observability(info, r))
    return {"method": method, "L": len(info.names), "gm": float(np.median(gm)),
            "worst": float(np.median(worst)), "opt": dz.observability(info, chosen),
            "rand_O1": float(np.median([o["O1"] for o in o_rand])),
            "rand_O3": float(np.median([o["O3"] for o in o_rand])), "t": t_design}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="designed poses (random: twice as many)")
    ap.add_argument("--pool", type=int, default=400)
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--methods", default=",".join(METHODS))
    a = ap.parse_args(argv)
    print(f"{a.n} D-optimal poses vs {2 * a.n} random, pool {a.pool}, median of {a.draws} "
          f"random draws")
    print(f"{'method':<20}{'L':>3}{'gm std ratio':>14}{'worst param':>13}"
          f"{'O1 opt/rand':>20}{'O3 opt/rand':>20}{'design s':>10}")
    for m in a.methods.split(","):
        r = compare(m, a.n, a.pool, a.draws)
        print(f"{m:<20}{r['L']:>3}{r['gm']:>14.3f}{r['worst']:>13.2f}"
              f"{r['opt']['O1']:>10.3g}/{r['rand_O1']:<9.3g}{r['opt']['O3']:>10.3g}/"
              f"{r['rand_O3']:<9.3g}{r['t']:>10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
