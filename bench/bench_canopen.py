"""Latency of the CANopen reads over the socketcand hub (simulator in another process).

    python bench/bench_canopen.py [--n 300] [--nodes 4]

Measures, for N rounds (after 20 warm-up rounds), each round calling every
operation once in turn (interleaved, so that load on the machine hits all alike):
  * SDO upload of 0x6064 from one drive, and from every drive (``read_sdo``);
  * one SYNC + every drive's TPDO (``sync_sample``), the station's sampling;
  * the same SYNC round trip with a bare python-can client (no canopen, no driver);
  * one ``read()`` (SYNC + TPDOs + conversion into a Sample);
and prints mean/median/p95 in ms, the SDO-versus-SYNC ratio and the software
overhead of ``read()`` beyond the bare bus round trip.
"""
from __future__ import annotations

import argparse
import multiprocessing
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import logging  # noqa: E402

import can  # noqa: E402

from drivers.canopen_drives import CanopenActuators  # noqa: E402
from drivers.sim.cia402_drive import run_sim_process  # noqa: E402

RES = 10000.0


def drain(bus: can.BusABC) -> None:
    """Drop the frames the other operations caused on the bare client's bus."""
    while bus.recv(0) is not None:
        pass


def bare_sync(bus: can.BusABC, nodes: list[int]):
    """SYNC with a plain python-can client; wait for one TPDO1 of every node."""
    def once():
        bus.send(can.Message(arbitration_id=0x80, data=[], is_extended_id=False))
        missing = {0x180 + n for n in nodes}
        end = time.monotonic() + 1.0
        while missing:
            msg = bus.recv(max(0.0, end - time.monotonic()))
            if msg is None:
                raise TimeoutError(f"bare SYNC: no TPDO from {sorted(m - 0x180 for m in missing)}")
            missing.discard(msg.arbitration_id)
    return once


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=300, help="repetitions per measurement")
    p.add_argument("--nodes", type=int, default=4, help="number of simulated drives")
    a = p.parse_args(argv)
    logging.getLogger("can.interfaces.socketcand").setLevel(logging.ERROR)  # split-TCP chatter
    nodes = list(range(1, a.nodes + 1))

    ctx = multiprocessing.get_context("spawn")
    conn, child = ctx.Pipe()
    proc = ctx.Process(target=run_sim_process, args=(child,), kwargs={"nodes": nodes, "resolution": RES},
                       daemon=True)
    proc.start()
    try:
        if not conn.poll(30):
            raise SystemExit("simulator did not start")
        _, endpoint = conn.recv()
        bus_kwargs = {k: v for k, v in endpoint.items() if k != "nodes"}
        with CanopenActuators.from_endpoint(endpoint, RES, timeout=1.0) as drv:
            bare = can.Bus(**bus_kwargs, tcp_tune=True)
            try:
                ops = {
                    "SDO read 0x6064, one drive": lambda: drv.sdo_read(nodes[0], 0x6064),
                    f"SDO read 0x6064, all {len(nodes)} drives": drv.read_sdo,
                    f"SYNC + {len(nodes)} TPDOs (driver)": drv.sync_sample,
                    f"SYNC + {len(nodes)} TPDOs (bare python-can)": bare_sync(bare, nodes),
                    "read() (SYNC + TPDOs -> Sample)": drv.read,
                }
                # interleaved: every round calls each operation once, in turn, so
                # that load on the machine hits all of them alike; the bare client's
                # queue (frames of the driver's operations) is emptied untimed
                bare_op = f"SYNC + {len(nodes)} TPDOs (bare python-can)"
                rows = {k: [] for k in ops}
                warm = min(20, a.n)
                for rnd in range(warm + a.n):
                    for name, fn in ops.items():
                        if name == bare_op:
                            drain(bare)
                        t0 = time.perf_counter()
                        fn()
                        if rnd >= warm:
                            rows[name].append(time.perf_counter() - t0)
            finally:
                bare.shutdown()
    finally:
        if proc.is_alive():
            conn.send(("stop",))
            proc.join(10)
        if proc.is_alive():
            proc.terminate()
            proc.join(5)

    print(f"\nCANopen over the socketcand hub on 127.0.0.1, {len(nodes)} simulated drives, n = {a.n}\n")
    print(f"{'operation':<40} {'mean ms':>9} {'median ms':>10} {'p95 ms':>8}")
    stats = {}
    for name, xs in rows.items():
        xs_ms = sorted(x * 1e3 for x in xs)
        stats[name] = (statistics.fmean(xs_ms), statistics.median(xs_ms), xs_ms[int(0.95 * (len(xs_ms) - 1))])
        print(f"{name:<40} {stats[name][0]:>9.3f} {stats[name][1]:>10.3f} {stats[name][2]:>8.3f}")
    names = list(rows)
    sdo_all, sync_drv, sync_bare, read = (stats[names[i]] for i in (1, 2, 3, 4))
    print(f"\nSDO (all drives) / SYNC+TPDO, mean:   {sdo_all[0] / sync_drv[0]:.2f}x"
          f"   median: {sdo_all[1] / sync_drv[1]:.2f}x")
    print(f"SDO (one drive)  / SYNC+TPDO, median: {stats[names[0]][1] / sync_drv[1]:.2f}x")
    print(f"read() overhead beyond the bare bus round trip: mean {read[0] - sync_bare[0]:.3f} ms, "
          f"median {read[1] - sync_bare[1]:.3f} ms")
    print(f"  of which canopen + driver SYNC bookkeeping: median {sync_drv[1] - sync_bare[1]:.3f} ms; "
          f"Sample building: median {read[1] - sync_drv[1]:.3f} ms")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
