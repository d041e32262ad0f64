"""Monte Carlo of the tracker path on drawn industrial arms: is the reported std honest?

Each run draws an arm around fixtures/robots/m10ia-like.urdf (joint origins off by
~1 mm / 1 mrad, zeros by 5 mrad), places a level tracker (z within 0.6 deg of the
base's) at random, fixes three reflectors on the tool, simulates FIT + HELD poses with
isotropic noise and some beams broken, writes the CSV the way the tracker and a FANUC
controller export it (mm, degrees, J3 from the horizontal), imports it with the joint
map and calibrates it through the gate (station.fitting.batch). The errors of the calibrated
parameters against the truth's equivalent (the fit of noise-free readings of the same
poses) are divided by the reported std; printed: success rate, RMS of error/std,
share within 2 std, and the pooled d2 = e^T C^-1 e against its chi-square interval.

    python bench/bench_urdf_markers.py                 # 30 arms, ~1 min
    python bench/bench_urdf_markers.py --arms 100 --noise 5e-5
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from station.simulation import tracegen_urdf as tg  # noqa: E402
from station.fitting.batch import calibrate_trace  # noqa: E402
from station.recording.import_markers import import_markers  # noqa: E402
from station.recording.trace_writer import write_trace  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"


def one(seed: int, tmp: Path, fit: int, held: int, noise: float):
    from calibration.robots import get_robot
    from drivers.urdf_file import load_urdf

    rob = get_robot(load_urdf(URDF, "base_link", "tool0"))
    x, _qm, _P = tg.tracker_export(tmp, rob, seed, fit=fit, held=held, noise=noise)
    got = import_markers(tmp / "meas.csv", URDF, base_link="base_link", tip_link="tool0",
                         length_unit="mm", angle_unit="deg", joint_map=tmp / "map.toml")
    write_trace(tmp / "t.jsonl", got.header, None, got.poses)
    out = calibrate_trace(str(tmp / "t.jsonl"))
    z, d2 = tg.errors_against_truth(out, x)
    held_rms = [v for v in out.validation or [] if v.get("points")]
    return z, d2, out.quality.passed, (held_rms[0]["points"]["rms_after"] if held_rms else None)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arms", type=int, default=30)
    ap.add_argument("--first-seed", type=int, default=7000)
    ap.add_argument("--fit", type=int, default=60)
    ap.add_argument("--held", type=int, default=20)
    ap.add_argument("--noise", type=float, default=3e-5, help="tracker noise per coordinate, m")
    a = ap.parse_args()
    zs, d2s, ok, held = [], [], 0, []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        for s in range(a.first_seed, a.first_seed + a.arms):
            try:
                z, d2, passed, h = one(s, Path(d), a.fit, a.held, a.noise)
            except Exception as e:  # noqa: BLE001 - a bench reports every failure
                print(f"seed {s}: FAILED {type(e).__name__}: {e}")
                continue
            ok += passed
            zs.append(z)
            d2s.append(d2)
            if h is not None:
                held.append(h)
            print(f"seed {s}: worst |z| {np.max(np.abs(z)):.2f}, RMS z {np.sqrt(np.mean(z**2)):.3f}, "
                  f"d2 {d2:.1f} on {len(z)}, gate {'passed' if passed else 'FAILED'}"
                  + (f", held-out 3D RMS {h * 1e3:.4f} mm" if h is not None else ""))
    allz = np.concatenate(zs)
    dof = sum(len(z) for z in zs)
    from scipy.special import chdtri

    lo, hi = chdtri(dof, 0.995), chdtri(dof, 0.005)
    print(f"\n{len(zs)} of {a.arms} arms calibrated, {ok} passed the gate "
          f"({time.perf_counter() - t0:.0f} s)")
    print(f"RMS error/std {np.sqrt(np.mean(allz ** 2)):.3f} over {allz.size} errors; "
          f"within 2 std {np.mean(np.abs(allz) < 2):.1%}; worst {np.max(np.abs(allz)):.2f}")
    print(f"pooled d2 {sum(d2s):.1f} on {dof} (an honest std's 99 %: {lo:.1f}-{hi:.1f})")
    if held:
        print(f"held-out 3D RMS median {np.median(held) * 1e3:.4f} mm (noise "
              f"{a.noise * 1e3 * math.sqrt(3):.4f} mm per point)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
