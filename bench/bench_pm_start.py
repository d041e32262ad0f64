"""Benchmark: the wrist's start fit (calibration.pm_start.robust_start_detail) at
100, 300, 1000 and 3000 poses (pm-fk, alpha+beta, noisy), time and peak memory
(tracemalloc, in a run of its own: the times are taken without it) and their growth
ratios per step of the pose count. Linear growth
shows as ratios at most the ratio of the pose counts; the joint-space fit on the
spread subset (START_SUBSET poses) is the constant part. With ``--dense`` the old
dense fit (every pose in one problem) runs too, up to 300 poses.

    python bench/bench_pm_start.py [--dense]
"""
from __future__ import annotations

import os
import sys
import time
import tracemalloc

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from calibration.methods import MethodData  # noqa: E402
from calibration.planning import PM_BOX, box_array, sample_poses  # noqa: E402
from calibration.pm_start import START_SUBSET, robust_start_detail  # noqa: E402
from calibration.robots.agebot_pm import TRUE, AgebotPM  # noqa: E402

COUNTS = (100, 300, 1000, 3000)
COMPS = ("alpha", "beta")


def data(m: int, seed: int = 1) -> MethodData:
    robot = AgebotPM()
    rng = np.random.default_rng(seed)
    plan = sample_poses(robot, TRUE, box_array(robot, PM_BOX), m, rng)
    X = plan.targets + 1.7e-4 * rng.normal(size=plan.targets.shape)
    return MethodData(plan.qm, {"orientation": X[:, :2]}, components=COMPS)


def measure(m: int, subset: int, repeats: int = 3) -> tuple[float, float, np.ndarray]:
    """(seconds, peak MiB, start x) of the start fit on ``m`` poses: the time is the
    best of ``repeats`` fits without tracemalloc (which slowed the fit 1.2-3.1x), the
    peak memory that of one more fit under tracemalloc (untimed)."""
    d, robot = data(m), AgebotPM()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = robust_start_detail(robot, d, robot.nominal, COMPS, subset=subset)
        times.append(time.perf_counter() - t)
    tracemalloc.start()
    robust_start_detail(robot, d, robot.nominal, COMPS, subset=subset)
    peak = tracemalloc.get_traced_memory()[1] / 2 ** 20
    tracemalloc.stop()
    return min(times), peak, out.x


def main(dense: bool = False) -> None:
    print(f"wrist start fit, pm-fk alpha+beta, subset {START_SUBSET} poses")
    print(f"{'poses':>6} {'time s':>8} {'peak MiB':>9} {'time ratio':>11} {'mem ratio':>10} "
          f"{'poses ratio':>12}")
    measure(20, START_SUBSET)          # warm-up: imports and caches are not the fit's
    prev = None
    for m in COUNTS:
        t, mem, _ = measure(m, START_SUBSET)
        ratios = ("", "", "") if prev is None else (
            f"{t / prev[1]:.2f}", f"{mem / prev[2]:.2f}", f"{m / prev[0]:.2f}")
        print(f"{m:>6} {t:>8.2f} {mem:>9.1f} {ratios[0]:>11} {ratios[1]:>10} {ratios[2]:>12}")
        prev = (m, t, mem)
    if dense:
        print("old dense fit (every pose in one joint-space problem):")
        for m in (100, 300):
            t, mem, _ = measure(m, 10 ** 9)
            print(f"{m:>6} {t:>8.2f} {mem:>9.1f}")


if __name__ == "__main__":
    main("--dense" in sys.argv[1:])
