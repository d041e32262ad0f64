"""Software overhead of one pose snapshot, from target reached to snapshot stored.

    python bench/bench_snapshot.py [--poses 15] [--incl-rate 100] [--trace-dir DIR]

The simulated AGEBOT SM station (``fixtures/stations/sim-sm.toml``, truth
``fixtures/truth/agebot-sm.json``) runs in a separate process: 4 CiA 402 drives
behind the socketcand hub, the inclinometer on a pseudo-terminal, the Modbus TCP
draw-wire, so the simulators' CPU does not count against the station process.
The station process opens the real drivers (``CanopenActuators``,
``Inclinometer``, ``DrawWire``) and, per pose:

  1. commands a small move and waits for target reached (not timed);
  2. ``snapshot_with(devices, SnapshotConfig(samples, period, settle))`` (timed:
     ``snapshot``);
  3. builds the pose record and appends it with ``station.recording.trace_writer.TraceWriter``
     (flush + fsync; timed: ``store``).

The rows (cases) are interleaved: each round measures one pose of every case in turn
(round 0 a warm-up), so that load on the machine falls on every row alike.

The configured budget of a snapshot is ``settle + (samples - 1) * period`` (the
sleeps; the last round's reads start at its end). Overhead = wall - budget; the
table gives it in ms and as a share of the budget, with the CANopen positions
read by SYNC + TPDO (the station's default) or by SDO (the fallback), and with
the inclinometer streaming at ``--incl-rate`` and at the simulator's default
20 Hz. A second table gives the per-device read latency inside the snapshots
and the bare read latency of the 4 drives by TPDO versus SDO (see
``bench_canopen.py`` for the CANopen details).

Columns: ``snapshot``: wall time of ``snapshot_with``; ``overhead`` = snapshot -
budget; ``last round``: the three device reads of the last sample round (always
overhead; the rest is sleep overshoot and the statistics); ``store``: pose record
+ ``TraceWriter.append`` (fsync); ``(ovh+store)/budget``: everything from target
reached to snapshot stored beyond the configured sleeps, relative to them.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import multiprocessing
import os
import random
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.canopen_drives import CanopenActuators  # noqa: E402
from drivers.config import load_station_config  # noqa: E402
from drivers.endpoints import with_endpoints  # noqa: E402
from drivers.rig import drawwire_from_config, inclinometer_from_config  # noqa: E402
from drivers.snapshot import snapshot_with  # noqa: E402
from station.recording.trace import read_trace  # noqa: E402
from station.recording.trace_writer import TraceWriter

CONFIG = ROOT / "fixtures" / "stations" / "sim-sm.toml"
TRUTH = ROOT / "fixtures" / "truth" / "agebot-sm.json"
# (samples, period s, settle s)
SETTINGS = ((5, 0.02, 0.05), (10, 0.05, 0.05))
SIM_INCL_RATE = 20.0            # SimInclinometer's default frame rate, Hz


def serve_station(conn, config_path, incl_rate) -> None:
    """Simulator process: the simulated AGEBOT SM and its three devices
    (:class:`drivers.sim.sim_station.SimStation`, shaped by the station config).

    Sends ``("ready", endpoints)`` (cli.md format), then serves ``("incl_rate", hz)``
    and ``("stop",)`` until stop or EOF.
    """
    from drivers.sim.sim_station import SimStation
    from drivers.sim.truth import load_truth

    station = SimStation(load_truth(TRUTH), load_station_config(config_path), seed=1,
                         inclinometer_hz=incl_rate, rtu=False, control=False)
    with station:
        conn.send(("ready", station.endpoints))
        while True:
            try:
                req = conn.recv()
            except (EOFError, OSError):
                break
            if req[0] == "incl_rate":
                station.inclinometer.period = 1.0 / float(req[1])
            conn.send(("ok", None))
            if req[0] == "stop":
                break


def open_devices(cfg, stack: contextlib.ExitStack):
    """The station's three drivers from the (resolved) station config, opened."""
    drives = stack.enter_context(CanopenActuators.from_config(cfg.canopen, name="drives"))
    incl = stack.enter_context(inclinometer_from_config(cfg.inclinometer))
    wire = stack.enter_context(drawwire_from_config(cfg.drawwire))
    return drives, incl, wire


def time_reads(devices, sink: dict[str, list[float]]) -> None:
    """Wrap each device's ``read`` to record its wall time (about 1 us added per read)."""
    for d in devices:
        def read(timeout=None, _orig=d.read, _name=d.name):
            t = time.perf_counter()
            try:
                return _orig(timeout)
            finally:
                sink[_name].append(time.perf_counter() - t)
        d.read = read


def pose_record(index: int, snap, n_axes: int) -> dict:
    """The trace's pose record of one snapshot (docs/file-formats.md)."""
    return {"record": "pose", "index": index,
            "qm": [snap.mean[f"qm{i + 1}"] for i in range(n_axes)],
            "distance": snap.mean["distance"], "tilt": snap.mean["tilt"], "t": snap.t_end,
            "samples": snap.samples, "std": dict(snap.std)}


def stats_ms(xs) -> tuple[float, float, float]:
    ms = sorted(x * 1e3 for x in xs)
    return statistics.fmean(ms), statistics.median(ms), ms[int(0.95 * (len(ms) - 1))]


def measure_pose(drives, devices, reads, writer, snap_cfg, q0, rng, index):
    """One pose: a small move (not timed), the snapshot and the stored record (timed);
    ``(snapshot s, store s, last round's reads s)``; ``reads`` gets the per-device
    read times of the snapshot (:func:`time_reads`)."""
    target = [q + rng.uniform(-0.3, 0.3) for q in q0]
    drives.move_to(target)
    drives.wait_target_reached(30.0)
    before = {n: len(v) for n, v in reads.items()}
    t0 = time.perf_counter()
    snap = snapshot_with(devices, snap_cfg)
    t1 = time.perf_counter()
    writer.append(pose_record(index, snap, len(q0)))
    t2 = time.perf_counter()
    last = sum(reads[d.name][-1] for d in devices)
    assert all(len(v) - before[n] == snap_cfg.samples for n, v in reads.items())
    return t1 - t0, t2 - t1, last


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=15, help="measured poses per case")
    p.add_argument("--incl-rate", type=float, default=100.0,
                   help="inclinometer frame rate, Hz (the simulator's default is 20)")
    p.add_argument("--n", type=int, default=200, help="repetitions of the bare TPDO/SDO reads")
    p.add_argument("--trace-dir", help="where the trace is written (default: a temporary folder)")
    a = p.parse_args(argv)
    logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)
    cfg = load_station_config(CONFIG)

    ctx = multiprocessing.get_context("spawn")
    conn, child = ctx.Pipe()
    proc = ctx.Process(target=serve_station, args=(child, CONFIG, a.incl_rate), daemon=True)
    proc.start()
    results, read_rows = [], {}
    try:
        if not conn.poll(60):
            raise SystemExit("simulator did not start")
        _, endpoints = conn.recv()
        cfg = with_endpoints(cfg, endpoints).require_resolved()
        with contextlib.ExitStack() as stack:
            drives, incl, wire = devices = open_devices(cfg, stack)
            drives.enable()
            wire.zero()
            q0 = [drives.read().values[ch] for ch in drives.channels]
            tmp = a.trace_dir or stack.enter_context(tempfile.TemporaryDirectory(prefix="bench-snapshot-"))
            path = Path(tmp) / f"bench-snapshot-{os.getpid()}.jsonl"
            writer = stack.enter_context(TraceWriter.create(path, {
                "robot": cfg.robot, "method": "sm-distance-tilt",
                "station": {"bench": "bench/bench_snapshot.py", "config": CONFIG.name}}))
            writer.append({"record": "reference", "role": "base-origin", "qm": q0})
            rng, index = random.Random(7), 0
            cases = [(s, via, a.incl_rate) for s in SETTINGS for via in ("tpdo", "sdo")]
            cases += [(s, "tpdo", SIM_INCL_RATE) for s in SETTINGS]
            rows = {case: [] for case in cases}
            sinks = {case: {d.name: [] for d in devices} for case in cases}
            current: dict[str, list[float]] = {}
            time_reads(devices, current)
            rate_now = None
            try:
                # interleaved: each round measures one pose of every case in turn, so
                # that a burst of load on the machine affects every case alike; round 0
                # is a warm-up
                for k in range(a.poses + 1):
                    for case in cases:
                        (samples, period, settle), via, rate = case
                        if rate != rate_now:
                            conn.send(("incl_rate", rate))
                            conn.recv()
                            time.sleep(0.2)             # a few frames at the new rate
                            rate_now = rate
                        drives.read_via = via
                        snap_cfg = dataclasses.replace(cfg.snapshot, samples=samples,
                                                       period=period, settle=settle)
                        current.clear()
                        current.update(sinks[case])
                        row = measure_pose(drives, devices, current, writer, snap_cfg, q0,
                                           rng, index)
                        index += 1
                        if k == 0:
                            for v in sinks[case].values():
                                v.clear()
                        else:
                            rows[case].append(row)
            finally:
                for d in devices:
                    del d.read                          # back to the class's method
            for case in cases:
                (samples, period, settle), via, rate = case
                results.append(((samples, period, settle), via, rate, rows[case]))
                read_rows[(samples, period, via, rate)] = sinks[case]
            drives.read_via = "tpdo"
            n_poses = len(read_trace(path).poses)
            bare = {"read() by SYNC + 4 TPDOs": [], "read_sdo(), 4 SDO uploads": []}
            for _ in range(a.n):
                for name, fn in zip(bare, (drives.read, drives.read_sdo), strict=True):
                    t = time.perf_counter()
                    fn()
                    bare[name].append(time.perf_counter() - t)
    finally:
        if proc.is_alive():
            with contextlib.suppress(OSError):
                conn.send(("stop",))
            proc.join(10)
        if proc.is_alive():
            proc.terminate()
            proc.join(5)

    print(f"\nSnapshot of one pose, simulated AGEBOT SM ({CONFIG.name}): 4 CiA 402 drives over the "
          f"socketcand hub + inclinometer (pty) + draw-wire (Modbus TCP); simulators in another "
          f"process; {a.poses} poses per row, medians (p95 in brackets); trace fsynced "
          f"({n_poses} poses read back)\n")
    head = (f"{'samples x period, settle':<25} {'CAN':<5} {'incl Hz':>7} {'budget ms':>9} "
            f"{'snapshot ms':>15} {'overhead ms':>15} {'ovh/budget':>10} {'last round ms':>13} "
            f"{'store ms':>13} {'(ovh+store)/budget':>18}")
    print(head)
    print("-" * len(head))
    for (samples, period, settle), via, rate, rows in results:
        budget = settle + (samples - 1) * period
        snap = [r[0] for r in rows]
        ovh = [r[0] - budget for r in rows]
        store = [r[1] for r in rows]
        last = [r[2] for r in rows]
        total = [r[0] + r[1] - budget for r in rows]
        s, o, st, la, to = (stats_ms(x) for x in (snap, ovh, store, last, total))
        print(f"{f'{samples} x {period * 1e3:g} ms, {settle * 1e3:g} ms':<25} {via:<5} {rate:>7g} "
              f"{budget * 1e3:>9.1f} {f'{s[1]:.1f} ({s[2]:.1f})':>15} {f'{o[1]:.2f} ({o[2]:.2f})':>15} "
              f"{o[1] / (budget * 1e3):>10.1%} {la[1]:>13.2f} {f'{st[1]:.2f} ({st[2]:.2f})':>13} "
              f"{to[1] / (budget * 1e3):>18.1%}")

    print("\nRead latency per device inside the snapshots (all rows of that kind), ms: "
          "median (p95)\n")
    print(f"{'CAN':<5} {'incl Hz':>7} {'drives':>15} {'inclinometer':>15} {'drawwire':>15}")
    merged: dict[tuple, dict[str, list[float]]] = {}
    for (_, _, via, rate), reads in read_rows.items():
        m = merged.setdefault((via, rate), {})
        for name, xs in reads.items():
            m.setdefault(name, []).extend(xs)
    for (via, rate), m in merged.items():
        cells = [stats_ms(m[n]) for n in ("drives", "inclinometer", "draw-wire")]
        print(f"{via:<5} {rate:>7g} " + " ".join(f"{f'{c[1]:.3f} ({c[2]:.3f})':>15}" for c in cells))

    print(f"\nCANopen positions of the 4 drives, bare reads, n = {a.n}, ms\n")
    print(f"{'read':<28} {'mean':>8} {'median':>8} {'p95':>8}")
    bs = {name: stats_ms(xs) for name, xs in bare.items()}
    for name, (mean, med, p95) in bs.items():
        print(f"{name:<28} {mean:>8.3f} {med:>8.3f} {p95:>8.3f}")
    (tp, sd) = bs.values()
    print(f"SDO / TPDO, median: {sd[1] / tp[1]:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
