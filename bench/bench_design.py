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
from station.planning.pose_design import DEFAULT_NOISE  # noqa: E402
from station.simulation.tracegen import candidate_pool  # noqa: E402


#: the built-in robots' methods (sm-position and sm-markers are a robot file's or a
#: URDF's: a tracker or motion capture on any arm, not simulated on the built-in arms)
BUILTIN_METHODS = tuple(m for m in METHODS if m not in ("sm-position", "sm-markers"))


def pool(method: str, pool_size: int, seed: int, robot_file: str | None):
    """``(model, group)``: the method's model over a pool of candidates planned on the
    planning model (the nominal arm, the true wrist; a robot file's nominal)."""
    if robot_file:
        from drivers.robot_file import load_robot_file
        from station.simulation import tracegen_serial as ts
        from station.planning.pose_design import pool_model

        robot = get_robot(load_robot_file(robot_file))
        _, ref, poses = ts.generate(robot, method, robot.nominal, count=pool_size, seed=seed)
        qm = np.array([p["qm"] for p in poses])
        group = np.array([p["group"] for p in poses]) if "group" in poses[0] else None
        return pool_model(method, robot, robot.nominal, qm, group=group,
                          reference_qm=None if ref is None else np.array(ref["qm"])), group
    robot = get_robot(BUILTIN[METHODS[method].kind])
    x_plan = robot.nominal if robot.name == "agebot-sm" else robot.true
    model, _, group = candidate_pool(method, x_plan, pool_size, seed=seed)
    return model, group


def compare(method: str, n: int | None, pool_size: int, draws: int, seed: int = 1,
            robot_file: str | None = None) -> dict:
    model, group = pool(method, pool_size, seed, robot_file)
    info = dz.pose_information(model, model.x0, DEFAULT_NOISE, group=group)
    if n is None:       # eq. 60's minimum for the identifiable set
        n = int(np.ceil(5 * len(info.names) / model.p))
    t0 = time.perf_counter()
    chosen = dz.d_optimal(info, n)
    t_design = time.perf_counter() - t0
    s_opt = dz.cramer_rao(info, chosen)
    rng = np.random.default_rng(seed)
    gm, gm_same, worst, o_rand = [], [], [], []
    for _ in range(draws):
        r = rng.choice(info.size, size=min(2 * n, info.size), replace=False)
        s_r = dz.cramer_rao(info, r)
        gm.append(dz.geometric_mean_std(s_opt) / dz.geometric_mean_std(s_r))
        worst.append(float(np.max(s_opt / s_r)))
        o_rand.append(dz.observability(info, r))
        r1 = rng.choice(info.size, size=n, replace=False)
        gm_same.append(dz.geometric_mean_std(s_opt) / dz.geometric_mean_std(dz.cramer_rao(info, r1)))
    return {"method": method, "n": n, "L": len(info.names), "gm": float(np.median(gm)),
            "gm_same": float(np.median(gm_same)),
            "worst": float(np.median(worst)), "opt": dz.observability(info, chosen),
            "rand_O1": float(np.median([o["O1"] for o in o_rand])),
            "rand_O3": float(np.median([o["O3"] for o in o_rand])), "t": t_design}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, help="designed poses (random: twice as many); default "
                    "20, and eq. 60's minimum with --robot-file")
    ap.add_argument("--robot-file", help="a robot file's arm (its methods: sm-position, "
                    "sm-distance, sm-distance-tilt, sm-full-pose)")
    ap.add_argument("--pool", type=int, default=400)
    ap.add_argument("--draws", type=int, default=50)
    ap.add_argument("--methods", default=",".join(BUILTIN_METHODS))
    a = ap.parse_args(argv)
    if a.robot_file and a.methods == ",".join(BUILTIN_METHODS):
        a.methods = "sm-position,sm-distance,sm-distance-tilt,sm-full-pose"
    n = a.n if a.n or a.robot_file else 20
    print(f"{n or 'eq. 60 minimum'} D-optimal poses (n) vs 2n random ('gm std ratio', "
          f"'worst param') and vs n random ('vs n random'), pool {a.pool}, median of "
          f"{a.draws} random draws{', robot file ' + a.robot_file if a.robot_file else ''}")
    print(f"{'method':<20}{'n':>4}{'L':>4}{'gm std ratio':>14}{'worst param':>13}"
          f"{'vs n random':>13}{'O1 opt/rand':>20}{'O3 opt/rand':>20}{'design s':>10}")
    for m in a.methods.split(","):
        r = compare(m, n, a.pool, a.draws, robot_file=a.robot_file)
        print(f"{m:<20}{r['n']:>4}{r['L']:>4}{r['gm']:>14.3f}{r['worst']:>13.2f}"
              f"{r['gm_same']:>13.3f}"
              f"{r['opt']['O1']:>10.3g}/{r['rand_O1']:<9.3g}{r['opt']['O3']:>10.3g}/"
              f"{r['rand_O3']:<9.3g}{r['t']:>10.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
