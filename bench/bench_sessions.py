"""Monte Carlo of whole simulated sessions over robots drawn around the nominal.

Each robot is drawn by ``drivers.sim.truth.draw_truth(robot, default_rng(seed))``
(gear ratios +-40 %, lengths +-5 %, offsets +-0.03) with the devices' noise
(``station.simulation.sessions.DEVICE_NOISE``); the simulator runs in its own process
and one unattended session (reference, plan, measure, calibrate, validate,
export) runs against it. The result is scored against the truth in the frame
the session captured (``station.simulation.sessions``).

Prints per session the worst |error|/std and the largest excursion from the
planned box, then the success rate, the worst normalized error, the RMS of
error/std (ideally 1), the coverage of the reported std (share of parameters
within 2 std, ideally ~95 %), the same of the errors whitened by each session's
reported correlation and their d2 = e^T Sigma^-1 e against its 99 % interval, the worst |error|/std per parameter and the
largest excursion::

    python bench/bench_sessions.py                         # 10 arms, sm-distance-tilt
    python bench/bench_sessions.py --robot agebot-sm --sessions 20 --first-seed 9100
    python bench/bench_sessions.py --method sm-distance --count 40
    python bench/bench_sessions.py --robot fixtures/robots/ur5-like-hayati.toml --count 40 \
        --validation 4 --first-seed 8800          # a robot file's arm (``equivalent_truth``)
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from station.planning.request import PlanRequest  # noqa: E402
from station.simulation.sessions import DEFAULT_METHOD, run_session, station_truth
from station.simulation.session_scores import d2_interval, summary

FIRST_SEED = {"agebot-sm": 9100, "agebot-pm": 9200}   # seeds not used by any other test

def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="agebot-sm",
                    help=f"{' or '.join(sorted(DEFAULT_METHOD))}, or a robot file's path")
    ap.add_argument("--method", default=None, help="default: sm-distance-tilt / pm-fk")
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=None)
    ap.add_argument("--count", type=int, default=None, help="fit poses (default: 2x eq. 60)")
    ap.add_argument("--validation", type=int, default=None)
    ap.add_argument("--speed", type=float, default=4.0, help="simulated moves this much faster")
    ap.add_argument("--keep", default=None, help="folder to keep the sessions in")
    ap.add_argument("--one-shot", action="store_true",
                    help="the arm's sessions planned at once (app.py run --one-shot)")
    a = ap.parse_args(argv)
    first = FIRST_SEED.get(a.robot, 8800) if a.first_seed is None else a.first_seed
    method = a.method or DEFAULT_METHOD.get(a.robot, "sm-distance-tilt")
    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_sessions_"))
    print(f"{a.sessions} {a.robot} sessions, {method}, seeds {first}..{first + a.sessions - 1}, "
          f"folder {root}")
    print(f"{'seed':>6} {'done':>5} {'poses':>6} {'skip':>5} {'worst z':>8} {'excursion':>40} "
          f"{'time':>6}  error")
    scores = []
    for seed in range(first, first + a.sessions):
        t0 = time.monotonic()
        req = PlanRequest(count=a.count, validation=a.validation, seed=seed)
        sc = run_session(station_truth(a.robot, seed), root / f"s{seed}", method=method,
                         seed=seed, request=req, speed=a.speed, grow=not a.one_shot)
        scores.append(sc)
        exc = " ".join(f"{k} {v:.3g}" for k, v in sc.excursion.items())
        print(f"{seed:>6} {str(sc.completed):>5} {sc.poses:>6} {sc.skipped:>5} {sc.worst:>8.2f} "
              f"{exc:>40} {time.monotonic() - t0:>5.0f}s  {sc.error[:120]}", flush=True)
    s = summary(scores)
    print()
    print(f"success rate        {s['completed']}/{s['sessions']} ({100 * s['success_rate']:.0f} %)")
    print(f"worst |error|/std   {s['worst']:.2f}")
    print(f"RMS error/std       {s['rms']:.3f} +- {s['rms_se']:.3f}   (over {s['n_errors']} "
          f"calibrated parameters; standard error with the sessions as the samples)")
    print(f"coverage of 2 std   {100 * s['coverage_2std']:.1f} +- "
          f"{100 * s['coverage_2std_se']:.1f} %   (ideal ~95 %)")
    if s["d2_k"]:
        lo, hi = d2_interval(s["d2_k"], s["d2_dof"], alpha=0.01)
        print(f"whitened by each session's reported correlation: RMS {s['rms_whitened']:.3f}, "
              f"{100 * s['coverage_2std_whitened']:.1f} % within 2; d2 {s['d2_sum']:.1f} on "
              f"{sum(s['d2_k'])} errors (an honest std's 99 %: {lo:.1f}-{hi:.1f})")
    if s["offset_exact_se"]:
        ex, rd = np.array(s["offset_exact_se"]), np.array(s["offset_reading_se"])
        um = np.array(s["offset_exact_um"])
        print("distance residuals at the true parameters, mean / its standard error:")
        print(f"  zero taken as exact   RMS {np.sqrt(np.mean(ex ** 2)):.1f} SE, worst {np.max(np.abs(ex)):.1f} SE "
              f"(worst {um[np.argmax(np.abs(um))]:+.1f} um)")
        print(f"  zero as a reading     RMS {np.sqrt(np.mean(rd ** 2)):.2f} SE, worst {np.max(np.abs(rd)):.2f} SE")
    if s["tool_error"] and np.isfinite(s["tool_error"]).any():
        te = 1e3 * np.array(s["tool_error"])
        print(f"tool position error over the whole box (true vs calibrated model): "
              f"mean {np.nanmean(te):.4f} mm, worst {np.nanmax(te):.4f} mm")
    for ch, v in s["heldout"].items():
        f = 1e3 if ch == "distance" else math.degrees(1)
        print(f"held-out {ch} RMS after: mean {f * np.nanmean(v):.4g} "
              f"{'mm' if ch == 'distance' else 'deg'}")
    print("worst |error|/std per parameter:")
    print("  " + ", ".join(f"{k} {v:.2f}" for k, v in s["worst_per_parameter"].items()))
    print("RMS of error/std per parameter (over the sessions):")
    print("  " + ", ".join(f"{k} {v[0]:.2f}" for k, v in s["rms_per_parameter"].items()))
    print("largest excursion from the planned box (m; rad for angles):")
    print("  " + ", ".join(f"{k} {v:.3g}" for k, v in s["excursion"].items()))
    ok = s["success_rate"] == 1.0 and math.isfinite(s["rms"])
    return 0 if ok else 1

if __name__ == "__main__":
    sys.exit(main())
