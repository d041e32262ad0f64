"""A simulated industrial arm seen by a laser tracker, exported as a user gets it:
the tracker's raw frame, millimetres, three reflectors, joint values in degrees as a
FANUC controller prints them (J3 counted from the horizontal):
:func:`station.simulation.tracegen_urdf.tracker_export`."""
from __future__ import annotations

from pathlib import Path

from calibration.robots import get_robot
from drivers.urdf_file import load_urdf
from station.simulation import tracegen_urdf as tg

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"


def arm():
    return get_robot(load_urdf(URDF, "base_link", "tool0"))


def tracker_case(tmp: Path, seed: int = 1, *, readings=None, **options):
    """``meas.csv`` and ``map.toml`` under ``tmp``: ``(robot, truth x with the points,
    joint values (m, 6) rad, readings (m, M, 3) m)``."""
    rob = arm()
    x, qm, P = tg.tracker_export(tmp, rob, seed, readings_override=readings, **options)
    return rob, x, qm, P


def import_args(tmp: Path, *extra):
    return ["trace", "import", str(tmp / "meas.csv"), "--robot", str(URDF), "--base-link",
            "base_link", "--tip-link", "tool0", "--method", "sm-markers", "--length-unit", "mm",
            "--angle-unit", "deg", "--joint-map", str(tmp / "map.toml"), "--out",
            str(tmp / "t.jsonl"), *extra]
