"""A simulated industrial arm seen by a laser tracker, exported as a user gets it:
the tracker's raw frame, millimetres, three reflectors, joint values in degrees as a
FANUC controller prints them (J3 counted from the horizontal)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calibration.robots import get_robot
from drivers.urdf_file import load_urdf
from station import tracegen_urdf as tg

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"

FANUC_MAP = """format = "calstation-joint-map"
version = 1
# the controller's J3 is counted from the horizontal: the URDF's joint_3 is J2 + J3
[[joint]]
urdf = "joint_3"
terms = { J2 = 1.0, J3 = 1.0 }
""" + "".join(f'[[joint]]\nurdf = "joint_{i}"\ncolumn = "J{i}"\n' for i in (1, 2, 4, 5, 6))


def arm():
    return get_robot(load_urdf(URDF, "base_link", "tool0"))


def tracker_case(tmp: Path, seed: int = 1, *, fit: int = 60, held: int = 20, noise: float = 3e-5,
                 points: int = 3, unseen: float = 0.05, tilt=0.6, readings=None, edit=None):
    """Write ``meas.csv`` and ``map.toml`` under ``tmp``; returns ``(robot, truth x with the
    points, joint values (m, 6) rad, readings (m, M, 3) m)``. ``readings`` replaces the
    simulated ones (same poses); ``edit(qm)`` changes the drawn poses in place first."""
    rob = arm()
    rng = np.random.default_rng(seed)
    x = tg.draw_truth(rob, rng)
    R, t = tg.draw_frame(rng, vertical_tilt_deg=tilt)
    x = tg.frame_parameters(rob, x, R, t)
    u = tg.draw_points(rng, points)
    qm = tg.draw_poses(rob, fit + held, rng)
    if edit is not None:
        edit(qm)
    P = tg.readings(rob, x, u, qm, rng, noise, unseen=unseen) if readings is None else readings
    deg = np.degrees(qm)
    cols = {"J1": deg[:, 0], "J2": deg[:, 1], "J3": deg[:, 2] - deg[:, 1], "J4": deg[:, 3],
            "J5": deg[:, 4], "J6": deg[:, 5]}
    (tmp / "meas.csv").write_text(tg.write_csv(cols, P, length_scale=1e-3,
                                               use=["fit"] * fit + ["validation"] * held))
    (tmp / "map.toml").write_text(FANUC_MAP)
    return rob, np.r_[x, u.reshape(-1)], qm, P


def import_args(tmp: Path, *extra):
    return ["trace", "import", str(tmp / "meas.csv"), "--robot", str(URDF), "--base-link",
            "base_link", "--tip-link", "tool0", "--method", "sm-markers", "--length-unit", "mm",
            "--angle-unit", "deg", "--joint-map", str(tmp / "map.toml"), "--out",
            str(tmp / "t.jsonl"), *extra]
