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


#: joint 5 of the arm turned as many ROS URDFs turn their frames (its axis z, its x along
#: joint 4's axis): the same robot, and joint 5's x the translation along joint 4's axis
#: (calibrated, the two differ by a milliradian: the near-dependency of the station's own
#: export of TIAGo; tests/station/test_urdf_recalibration.py, the sweep's u43 cases)
TURNED_WRIST = (
    ('<origin xyz="0.4595 -0.0565 0" rpy="0 0 0"/>',
     '<origin xyz="0.4595 -0.0565 0" rpy="-1.5707963267948966 0 3.141592653589793"/>'),
    ('<child link="link_5"/>\n    <axis xyz="0 -1 0"/>',
     '<child link="link_5"/>\n    <axis xyz="0 0 1"/>'),
    # joint 6's origin in the turned frame (R^T of it; R = R^T): the same chain
    ('<origin xyz="0.1 0.0565 0" rpy="0 0 0"/>',
     '<origin xyz="-0.1 0 -0.0565" rpy="-1.5707963267948966 0 3.141592653589793"/>'))


def turned_wrist(text: str) -> str:
    """The arm's URDF ``text`` with joint 5's frame turned (:data:`TURNED_WRIST`)."""
    for old, new in TURNED_WRIST:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


def rail_export(folder: Path, seed: int) -> tuple[Path, Path]:
    """The arm on a 2 m linear rail (a prismatic first joint ``rail``) seen by a tracker,
    its controller printing the rail in m and the joints in degrees beside the tracker's
    mm: ``(folder/rail.urdf, folder/meas.csv)``."""
    import numpy as np

    text = URDF.read_text()
    old = ('<joint name="joint_1" type="revolute">\n    <origin xyz="0 0 0" rpy="0 0 0"/>\n'
           '    <parent link="base_link"/>')
    assert text.count(old) == 1
    urdf = folder / "rail.urdf"
    urdf.write_text(text.replace(old, (
        '<joint name="rail" type="prismatic">\n    <origin xyz="0 0 0" rpy="0 0 0"/>\n'
        '    <parent link="base_link"/>\n    <child link="carriage"/>\n    <axis xyz="1 0 0"/>\n'
        '    <limit lower="0" upper="2.0" effort="0" velocity="1.0"/>\n  </joint>\n'
        '  <link name="carriage"/>\n'
        '  <joint name="joint_1" type="revolute">\n    <origin xyz="0 0 0" rpy="0 0 0"/>\n'
        '    <parent link="carriage"/>')))
    rob = get_robot(load_urdf(urdf, "base_link", "tool0"))
    rng = np.random.default_rng(seed)
    x = tg.frame_parameters(rob, tg.draw_truth(rob, rng),
                            *tg.draw_frame(rng, vertical_tilt_deg=0.5))
    qm = tg.draw_poses(rob, 60, rng)
    P = tg.readings(rob, x, tg.draw_points(rng, 3), qm, rng, 3e-5)
    cols = {"rail": qm[:, 0]} | {f"joint_{i}": np.degrees(qm[:, i]) for i in range(1, 7)}
    csv = folder / "meas.csv"
    csv.write_text(tg.write_csv(cols, P, length_scale=1e-3))
    return urdf, csv
