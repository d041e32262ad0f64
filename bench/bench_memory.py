"""Peak memory of a large headless calibration (issue 43): a laser tracker's export of
the m10ia-like arm with N poses (three reflectors, a fifth held out), imported, then
``app.py batch``: the import's and the batch's own peak resident memory and wall time,
each in a fresh process (``os.wait4``: that process's figures, not the bench's).

    python bench/bench_memory.py                    # 100 000 poses, ~3 min
    python bench/bench_memory.py --poses 20000
    python bench/bench_memory.py --root OTHER       # another checkout (before/after)

The target: the 100 000-pose batch below 1 GB.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))


def measured(cmd, cwd) -> tuple[int, float, float]:
    """``(exit code, peak RSS MB, wall s)`` of ``cmd`` run in its own process."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _pid, status, usage = os.wait4(p.pid, 0)
    p.returncode = os.waitstatus_to_exitcode(status)
    err = p.stderr.read().decode(errors="replace")
    if p.returncode:
        sys.exit(f"{' '.join(map(str, cmd[1:4]))} ...: exit {p.returncode}: {err.strip()[-300:]}")
    return p.returncode, usage.ru_maxrss / 1024.0, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=100_000)
    ap.add_argument("--root", default=str(HERE), help="the checkout whose app.py runs")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    from station.simulation import tracegen_urdf as tg
    from tests.station.urdf_helpers import URDF, arm

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        held = a.poses // 5
        t = time.perf_counter()
        tg.tracker_export(d, arm(), a.seed, fit=a.poses - held, held=held)
        print(f"{a.poses} poses exported in {time.perf_counter() - t:.0f} s", flush=True)
        app = [sys.executable, str(Path(a.root) / "app.py")]
        _, rss, wall = measured(app + ["trace", "import", str(d / "meas.csv"), "--robot", str(URDF),
                                       "--base-link", "base_link", "--tip-link", "tool0",
                                       "--method", "sm-markers", "--length-unit", "mm",
                                       "--angle-unit", "deg", "--joint-map", str(d / "map.toml"),
                                       "--out", str(d / "t.jsonl")], a.root)
        print(f"trace import: peak {rss:.0f} MB, {wall:.1f} s", flush=True)
        _, rss, wall = measured(app + ["batch", str(d / "t.jsonl"), "--out", str(d / "p.json")],
                                a.root)
        print(f"batch:        peak {rss:.0f} MB, {wall:.1f} s (target below 1024 MB at 100 000 "
              f"poses)")


if __name__ == "__main__":
    main()
