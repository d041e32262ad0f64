"""The arm's robot-idle planning: how long the arm waits while the station refits its
model and plans the next round (:meth:`station.planning.arm_rounds.ArmRounds.next_round`)
or re-plans after an envelope stop (``replan_after_stop``), over whole unattended
sessions of arms drawn around the nominal (the simulator in its own process, as
``bench_sessions.py`` runs them).

    python bench/bench_planning.py [--method sm-distance] [--sessions 8] [--first-seed 9130]

Every planning call is timed (wall and this thread's CPU) inside the session, the
scout's first plan left out (it is planned before the arm moves). Prints each session's
calls, then per method the median, 90th percentile and largest wall time and how many
calls took over ``--limit`` s (issue 24: 0.2 s per round on 2 cores). Sessions are
not repeatable (the envelope reads against the wall clock), so compare two versions
on the same seeds run one after the other, not one call against another.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import station.outputs.report  # noqa: E402
from station.planning import arm_rounds  # noqa: E402
from station.planning.request import PlanRequest  # noqa: E402
from station.simulation.sessions import run_session, station_truth  # noqa: E402

CALLS = ("next_round", "replan_after_stop")


def _timed(calls: list):
    """Wrap the planning calls of :class:`ArmRounds` to append ``(name, wall, cpu)``."""
    for name in CALLS:
        f = getattr(arm_rounds.ArmRounds, name)

        def wrapper(self, *a, _f=f, _n=name, **k):
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return _f(self, *a, **k)
            finally:
                calls.append((_n, time.perf_counter() - t0, time.thread_time() - c0))

        setattr(arm_rounds.ArmRounds, name, wrapper)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", action="append", choices=("sm-distance", "sm-distance-tilt"),
                    help="repeatable; default both")
    ap.add_argument("--sessions", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=None,
                    help="default 9130 (sm-distance) and 9700 (sm-distance-tilt)")
    ap.add_argument("--limit", type=float, default=0.2, help="s per planning call")
    args = ap.parse_args(argv)
    # the report's figures are not what is timed here (and take 2 s of CPU each)
    station.outputs.report.write_report = lambda path, *a, **k: Path(path).write_text("report\n")
    calls: list = []
    _timed(calls)
    for method in args.method or ("sm-distance", "sm-distance-tilt"):
        first = args.first_seed or (9130 if method == "sm-distance" else 9700)
        count = 30 if method == "sm-distance" else 24
        walls = []
        for seed in range(first, first + args.sessions):
            calls.clear()
            with tempfile.TemporaryDirectory() as d:
                sc = run_session(station_truth("agebot-sm", seed), Path(d) / "s", seed=seed,
                                 method=method,
                                 request=PlanRequest(count=count, validation=4, seed=seed))
            got = [(n, w, c) for n, w, c in calls if w > 1e-3]  # not the last, empty call
            walls += [w for _, w, _ in got]
            state = "passed" if sc.completed else f"stopped: {sc.error[:60]}"
            print(f"{method} seed {seed} ({state}): " + ", ".join(
                f"{'round' if n == 'next_round' else 'replan'} {w:.3f} s (cpu {c:.3f})"
                for n, w, c in got), flush=True)
        a = np.array(walls)
        if a.size:
            print(f"{method}: {a.size} planning calls in {args.sessions} sessions; wall median "
                  f"{np.median(a):.3f} s, 90 % {np.quantile(a, 0.9):.3f} s, largest {a.max():.3f} s; "
                  f"over {args.limit} s: {int(np.sum(a > args.limit))}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
