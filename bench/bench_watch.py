"""The watched move's overhead: :func:`station.planning.envelope.watched_move` against a plain
move to the same target (:meth:`drivers.rig.Rig.move_to`, which waits for the drives'
target reached), on the simulated arm in its own process (4 CiA 402 drives behind the
socketcand hub, the inclinometer, the Modbus draw-wire; the fixture's speeds).

    python bench/bench_watch.py [--moves 20] [--poll 0.05]

Per round, interleaved after a warm-up round: the same small moves out and back,
plain, watched waking at the predicted arrival (the station's), and watched with the
fixed poll of before (``nap = poll``). Overhead of a watched move = its wall time
minus the plain move's median, in ms (median and 90th percentile over the moves);
every move is checked at its target before a time counts.
"""
from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from calibration.robots import get_robot  # noqa: E402
from drivers.rig import Rig  # noqa: E402
from drivers.sim.server import SimulatorProcess  # noqa: E402
from drivers.sim.truth import load_truth  # noqa: E402
from station.planning import envelope  # noqa: E402
from station.simulation.sessions import fast_config  # noqa: E402

TRUTH = ROOT / "fixtures" / "truth" / "agebot-sm-unseen.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--moves", type=int, default=20, help="moves per variant and round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--poll", type=float, default=0.05, help="[envelope] poll, s")
    args = ap.parse_args(argv)
    robot = get_robot("agebot-sm")
    truth = load_truth(TRUTH).xi()
    rng = np.random.default_rng(5)
    with tempfile.TemporaryDirectory() as tmp:
        cfg = fast_config("agebot-sm", Path(tmp), 1.0)
        with SimulatorProcess("agebot-sm", truth=str(TRUTH), config=str(cfg), seed=3) as sim, \
                Rig(sim.station_config()) as rig:
            env = dataclasses.replace(rig.config.envelope, poll=args.poll)
            home = np.array(rig.qm())
            rig.zero_drawwire()
            steps = rng.uniform(-1, 1, (args.moves, 4)) * np.array([2.0, 15.0, 15.0, 15.0])
            predict = envelope.sm_predictor("sm-distance-tilt", robot, truth, home)
            wake = envelope.nap

            def plain(target):
                rig.move_to(target)

            def watched(target):
                envelope.watched_move(rig, target, predict, env, 20.0)

            def polled(target):
                envelope.nap = lambda poll, arrival: poll
                try:
                    envelope.watched_move(rig, target, predict, env, 20.0)
                finally:
                    envelope.nap = wake

            variants = {"plain move": plain, "watched, wakes at arrival": watched,
                        "watched, fixed poll": polled}
            times = {k: [] for k in variants}
            for rnd in range(args.rounds + 1):          # round 0: warm-up
                for step in steps:
                    for name, fn in variants.items():
                        for target in (home + step, home):
                            t = time.perf_counter()
                            fn(target)
                            dt = time.perf_counter() - t
                            if np.max(np.abs(np.array(rig.qm()) - target)) > 1e-3:
                                raise SystemExit(f"{name}: not at the target")
                            if rnd:
                                times[name].append(dt)
    base = statistics.median(times["plain move"])
    print(f"{len(times['plain move'])} moves per variant, poll {args.poll * 1e3:g} ms; "
          f"plain move median {base * 1e3:.1f} ms")
    print(f"{'variant':28s} {'median ms':>10s} {'overhead ms':>12s} {'p90 overhead':>13s}")
    for name, t in times.items():
        over = np.array(t) - base
        print(f"{name:28s} {statistics.median(t) * 1e3:10.1f} {np.median(over) * 1e3:12.1f} "
              f"{np.percentile(over, 90) * 1e3:13.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
