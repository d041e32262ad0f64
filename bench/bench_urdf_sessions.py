"""Monte Carlo of whole simulated sessions of a URDF robot measured by a motion capture
(``sm-markers`` at the station): is the reported uncertainty of the calibrated points
honest?

Each robot is drawn around the URDF's nominal as ``app.py truth draw`` draws it
(``station.simulation.urdf_sessions.urdf_truth``, seeds FIRST..FIRST+N-1: joint origins
off by ~1 mm / 1 mrad, zeros by ~5 mrad, a motion-capture room placed at random, three
markers on the tool); the simulator runs in its own process with the room's ``[mocap]``
and one unattended session (scout, middle and last round, calibrate, validate, export)
runs against it (``station.simulation.urdf_sessions.run_urdf_session``). The result is
scored by its predictions, not its parameters (the points on the tool and some joint
parameters trade off): at 200 poses drawn inside the joint limits, each point's error
against the truth and its reported covariance ``J C J^T``
(``station.simulation.urdf_scores``).

Prints per session: refused (the station's named refusal) or not, recorded and skipped
poses, the held-out points' 3D RMS the session printed (mm), the whitened RMS of its
predicted points (``sqrt(mean(d2/3))``, 1 for an honest std) and their coverage of the
95 % ellipsoid; then the sessions refused or failed, the whitened RMS over all (target
0.8-1.3) with its standard error (the sessions as the samples), the coverage of the
95 % ellipsoid (ideal 95 %), the RMS error and reported std of the predicted points and
the mean held-out error::

    python bench/bench_urdf_sessions.py                   # 20 sessions, ~15 min on 2 cores
    python bench/bench_urdf_sessions.py --sessions 5 --first-seed 40 --keep /tmp/u
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from drivers.robot_file import urdf_ref
from station.planning.request import PlanRequest
from station.simulation.urdf_scores import summary
from station.simulation.urdf_sessions import SPEED, run_urdf_session, urdf_truth

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"
RMS_TARGET = (0.8, 1.3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=str(URDF), help="a URDF (default: the M-10iA-like arm)")
    ap.add_argument("--base-link", default="base_link")
    ap.add_argument("--tip-link", default="tool0")
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--count", type=int, default=None, help="fit poses (default: 2x eq. 60)")
    ap.add_argument("--validation", type=int, default=None)
    ap.add_argument("--frames", type=int, default=None,
                    help="motion-capture frames averaged per reading (default: the room's)")
    ap.add_argument("--speed", type=float, default=SPEED, help="simulated moves this much faster")
    ap.add_argument("--keep", default=None, help="folder to keep the sessions in")
    a = ap.parse_args(argv)
    ref = urdf_ref(a.robot, a.base_link, a.tip_link)
    root = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_urdf_sessions_"))
    last = a.first_seed + a.sessions - 1
    print(f"{a.sessions} sessions of {ref}, sm-markers, seeds {a.first_seed}..{last}, "
          f"folder {root}")
    print(f"{'seed':>5} {'refused':>7} {'poses':>5} {'skip':>4} {'held-out mm':>11} "
          f"{'whitened':>8} {'in 95%':>6} {'err mm':>7} {'std mm':>7} {'time':>5}  error")
    scores = []
    for seed in range(a.first_seed, last + 1):
        truth, _x = urdf_truth(ref, seed, f"drawn by bench_urdf_sessions, seed {seed}")
        req = PlanRequest(count=a.count, validation=a.validation, seed=seed)
        t0 = time.monotonic()
        sc = run_urdf_session(truth, ref, root / f"s{seed}", seed=seed, request=req,
                              speed=a.speed, frames=a.frames)
        scores.append(sc)
        print(f"{seed:>5} {'yes' if sc.refused else 'no':>7} {sc.poses:>5} {sc.skipped:>4} "
              f"{1e3 * sc.heldout:>11.4f} {sc.whitened_rms:>8.3f} {100 * sc.coverage95:>5.1f}% "
              f"{1e3 * sc.error_rms:>7.4f} {1e3 * sc.std_rms:>7.4f} "
              f"{time.monotonic() - t0:>4.0f}s  {sc.error[:120]}", flush=True)
    s = summary(scores)
    lo, hi = RMS_TARGET
    print()
    print(f"sessions refused    {s['refused']} of {s['sessions']} (failed otherwise: {s['failed']})")
    print(f"whitened RMS        {s['whitened_rms']:.3f} +- {s['whitened_rms_se']:.3f}   (over "
          f"{s['completed']} sessions x 200 poses x points; target {lo}-{hi}; standard error "
          f"with the sessions as the samples)")
    print(f"coverage of the 95 % ellipsoid  {100 * s['coverage95']:.1f} %")
    print(f"predicted points: RMS error {1e3 * s['error_rms']:.4f} mm, reported std "
          f"{1e3 * s['std_rms']:.4f} mm (3D)")
    print(f"mean held-out error (the sessions' 3D RMS)  {1e3 * s['heldout_mean']:.4f} mm")
    ok = (s["refused"] == 0 and s["failed"] == 0 and math.isfinite(s["whitened_rms"])
          and lo <= s["whitened_rms"] <= hi)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
