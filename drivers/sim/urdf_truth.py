"""A simulated URDF robot's truth (docs/urdf-robots.md, "A simulated URDF robot's truth")::

    {"robot": "urdf", "urdf": "arm-true.urdf", "base_link": "base", "tip_link": "tool",
     "measurement_frame": {"xyz": [1.8, -0.6, -0.9], "rpy": [0.01, -0.02, 2.4]},
     "points_on_tool": [[0.03, 0.04, 0.06], [0.05, -0.05, 0.04]],
     "noise": {"marker": 5e-5}, "seed": 7}

``urdf`` is the TRUE robot (relative to the truth file), a URDF with the same links and
joints as the nominal's; ``measurement_frame`` the base link's pose in the instrument's
frame (m, rad; ``R = Rz(yaw) Ry(pitch) Rx(roll)``); ``points_on_tool`` the points in the
tip link's frame (m), in the instrument's order; ``noise.marker`` the std of each
coordinate (m). Optional: ``noise`` of the station's own sensors (``distance``, ``roll``,
``pitch``, ``qm``: as a robot file's truth), ``inclinometer_mount``, ``comment``, and
``repeatability``: ``{"backlash": rad, "positioning": rad}`` (m for a prismatic joint;
one number or one per joint of the chain): each joint's whole backlash and the std of
a random positioning error per move, between the drive's encoder and the link
(:mod:`drivers.sim.truth`, :mod:`drivers.sim.axis`); left out, the link is where the
motor is, as before.

The simulated robot is the true URDF as it is, in its base link's frame (its floor is
the base link's ``z = 0``); the instrument sees its points through the measurement frame.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from drivers.config_reader import KeyReader, frozen_map

NOISE = ("marker", "distance", "tilt", "roll", "pitch", "qm")


def parse_urdf_truth(top: KeyReader, source: str | None) -> dict:
    """The :class:`~drivers.sim.truth.SimTruth` fields of a URDF robot's truth object
    (``top``, its ``robot`` is ``"urdf"``); errors name ``source`` and the key."""
    from calibration.robots import get_robot
    from drivers.urdf_file import load_urdf

    top.choice("robot", ("urdf",))
    path = top.str("urdf")
    base = Path(source).parent if source else Path(".")
    spec = load_urdf(base / path, top.str("base_link"), top.str("tip_link"))
    fr = top.table("measurement_frame")
    xyz = fr.float_list("xyz", length=3)
    rpy = fr.float_list("rpy", length=3)
    fr.finish()
    pts = top.data.get("points_on_tool")
    if not isinstance(pts, list) or not pts:
        top.fail("points_on_tool", "expected a list of points [x, y, z] (m, the tip link's "
                 "frame), at least one")
    pr = KeyReader(dict(enumerate(pts)), "points_on_tool", source, indexed=True)
    points = tuple(tuple(pr._list(i, 3, None, False, lambda s, k: s.float(k))) for i in
                   range(len(pts)))
    top._used.add("points_on_tool")
    for i, p in enumerate(points):
        if max(abs(v) for v in p) > 2.0:
            pr.fail(i, "a point on the tool is within 2 m of the tip link's origin")
    noise = {}
    nr = top.table("noise", required=False)
    if nr is not None:
        for ch in nr.keys():
            if ch not in NOISE:
                nr.fail(ch, f"unknown channel (known: {', '.join(NOISE)})")
            noise[ch] = nr.float(ch, lo=0.0)
    seed = top.int("seed", default=None, lo=0)
    mount = (0.0, 0.0)
    if "inclinometer_mount" in top.data:
        mount = top.float_list("inclinometer_mount", length=2)
        if max(abs(m) for m in mount) > math.pi / 4:
            top.fail("inclinometer_mount", "a mounting rotation is small: |rx|, |ry| <= pi/4")
    from drivers.sim.repeatability import parse_repeatability

    repeatability = parse_repeatability(top, len(spec.joints))
    comment = top.str("comment", default=None)
    top.finish()
    model = get_robot(spec)
    return dict(robot="urdf", parameters=frozen_map(model.as_dict(model.nominal)),
                noise=frozen_map(noise), seed=seed, inclinometer_mount=tuple(mount),
                comment=comment, source=source, spec=spec, robot_file=path,
                frame=(tuple(xyz), tuple(rpy)), points=points, repeatability=repeatability)


def urdf_truth_dict(truth) -> dict[str, Any]:
    """What a URDF robot's truth object has of its own (inverse of
    :func:`parse_urdf_truth`); :func:`drivers.sim.truth.truth_to_dict` adds the keys every
    truth has (noise, seed, inclinometer_mount, repeatability, comment)."""
    return {"robot": "urdf", "urdf": truth.robot_file,
            "base_link": truth.spec.base_link, "tip_link": truth.spec.tip_link,
            "measurement_frame": {"xyz": list(truth.frame[0]), "rpy": list(truth.frame[1])},
            "points_on_tool": [list(p) for p in truth.points]}


def frame_matrix(frame) -> np.ndarray:
    """``(4, 4)`` the base link in the instrument's frame from ``(xyz, rpy)``."""
    from calibration.robots.serial import rpy_matrix

    T = np.eye(4)
    T[:3, :3] = rpy_matrix(frame[1])[0]
    T[:3, 3] = frame[0]
    return T


def same_chain(a, b) -> str | None:
    """Why two URDF robots' chains are not the same robot's (links, joints, kinds), else
    None: a truth's true URDF must be the nominal's robot."""
    if (a.base_link, a.tip_link) != (b.base_link, b.tip_link):
        return (f"its chain is {a.base_link} to {a.tip_link}, the robot's {b.base_link} to "
                f"{b.tip_link}")
    ja = [(j.name, j.kind) for j in a.joints]
    jb = [(j.name, j.kind) for j in b.joints]
    if ja != jb:
        return (f"its joints are {', '.join(n for n, _ in ja)}, the robot's "
                f"{', '.join(n for n, _ in jb)}")
    return None


def true_points(truth, model, xi, qm) -> np.ndarray:
    """``(M, 3)`` the truth's points on the tool in the instrument's frame (m) with the
    robot at ``qm``: ``T_frame T_tip(qm) u_j``."""
    T = frame_matrix(truth.frame) @ model.frames(np.atleast_2d(qm), xi)[0]
    u = np.asarray(truth.points, dtype=float)
    return u @ T[:3, :3].T + T[:3, 3]


def seen_mask(truth, model, xi, qm, volume, viewpoint, max_angle: float, outward=None):
    """``(M,)`` which of the truth's points the instrument sees with the robot at ``qm``:
    inside the measuring ``volume`` ``((3,), (3,))`` (min, max; instrument frame, m) and
    facing the ``viewpoint`` within ``max_angle`` (rad; a point's outward direction:
    ``outward (M, 3)`` in the tip link's frame, default its own direction from the tip
    link's origin; a point within 1 cm of it is seen from everywhere)."""
    T = frame_matrix(truth.frame) @ model.frames(np.atleast_2d(qm), xi)[0]
    u = np.asarray(truth.points, dtype=float)
    p = u @ T[:3, :3].T + T[:3, 3]
    inside = np.all((p >= np.asarray(volume[0])) & (p <= np.asarray(volume[1])), axis=1)
    d = np.asarray(outward, dtype=float) if outward is not None else u
    n = np.linalg.norm(d, axis=1)
    out = (d / np.where(n > 0, n, 1.0)[:, None]) @ T[:3, :3].T
    sight = np.asarray(viewpoint, dtype=float) - p
    sight /= np.maximum(np.linalg.norm(sight, axis=1), 1e-12)[:, None]
    facing = (np.einsum("mk,mk->m", out, sight) >= np.cos(max_angle)) | (n < 0.01)
    return inside & facing
