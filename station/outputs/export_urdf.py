"""The calibrated robot written into its own URDF (``app.py params export --urdf`` of a
URDF robot; docs/urdf-robots.md, "Export").

Only the ``<origin>`` of the chain's movable joints changes: each becomes the joint's
origin with its calibration in it (:meth:`calibration.robots.urdf.UrdfRobot.calibrated_origins`:
the correction of the origin and the joint's zero offset), so that the URDF driven by
the joint values of the CSV (in SI) puts the tip where the parameter file does. Every
other byte of the file is kept: names, other joints, visuals, collisions, inertials,
transmissions, comments, formatting. The elements are located with the standard
library's expat parser (byte positions), and the new values are written with 17
significant digits; rpy is solved to round-off, also at pitch = +-pi/2 where URDF's
angles are degenerate (there a small turn can change roll and yaw by a lot while the
rotation barely moves: the values differ, the frame does not). An origin the
calibration left where it was is not rewritten.
"""
from __future__ import annotations

import math
import xml.parsers.expat

import numpy as np

from calibration.errors import ConfigError
from calibration.robots.serial import rpy_matrix, rpy_of


# An origin within this of the URDF's (round-off of turning it back and forth) is
# left exactly as it was written.
UNCHANGED = 1e-15


def rpy_exact(R: np.ndarray) -> np.ndarray:
    """``(roll, pitch, yaw)`` with ``Rz(yaw) Ry(pitch) Rx(roll) = R`` to round-off: the
    closed form, then Gauss-Newton on the rotation's error (which the closed form
    leaves at ~1e-5 where ``cos(pitch)`` is ~1e-11, as in URDFs written with
    ``pitch = 1.57079632679``)."""
    R = np.asarray(R, dtype=float)
    rpy = rpy_of(R[None])[0]
    for _ in range(4):
        E = R @ rpy_matrix(rpy)[0].T          # the error as a rotation in the base frame
        e = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
        if np.max(np.abs(e)) < 1e-17:
            break
        r, p, y = rpy
        # spatial angular velocity per rate of roll, pitch, yaw (R = Rz(y) Ry(p) Rx(r))
        J = np.column_stack([
            [math.cos(y) * math.cos(p), math.sin(y) * math.cos(p), -math.sin(p)],
            [-math.sin(y), math.cos(y), 0.0],
            [0.0, 0.0, 1.0]])
        rpy = rpy + np.linalg.lstsq(J, e, rcond=1e-14)[0]
    return rpy


def _attr(v: float) -> str:
    return repr(float(v)) if v != 0 else "0"


def origin_element(T: np.ndarray) -> str:
    rpy = rpy_exact(T[:3, :3])
    return (f'<origin xyz="{" ".join(_attr(v) for v in T[:3, 3])}" '
            f'rpy="{" ".join(_attr(v) for v in rpy)}"/>')


def _tag_end(data: bytes, start: int) -> int:
    """Index just past the ``>`` that ends the tag starting at ``start`` (quotes
    respected)."""
    i, quote = start, None
    while i < len(data):
        c = data[i:i + 1]
        if quote:
            if c == quote:
                quote = None
        elif c in (b'"', b"'"):
            quote = c
        elif c == b">":
            return i + 1
        i += 1
    raise ConfigError("the URDF ends inside a tag", source="URDF export")


def joint_origin_spans(text: str, names) -> dict:
    """Per joint name: ``(start, end, insert)`` byte positions in ``text`` (UTF-8) of its
    direct ``<origin>`` child (start = end = None where it has none) and of the end of
    its own start tag (where a missing origin goes)."""
    data = text.encode("utf-8")
    wanted = set(names)
    out: dict = {}
    stack: list = []
    parser = xml.parsers.expat.ParserCreate()

    def start(tag, attrs):
        pos = parser.CurrentByteIndex
        stack.append((tag, attrs.get("name"), pos))
        if tag == "joint" and attrs.get("name") in wanted and len(stack) == 2:
            out[attrs["name"]] = [None, None, _tag_end(data, pos)]
        elif (tag == "origin" and len(stack) == 3 and stack[-2][0] == "joint"
              and stack[-2][1] in out):
            out[stack[-2][1]][0] = pos

    def end(tag):
        _t, name, pos0 = stack.pop()
        pos = parser.CurrentByteIndex
        if tag == "origin" and len(stack) == 2 and stack[-1][0] == "joint" and stack[-1][1] in out:
            rec = out[stack[-1][1]]
            if rec[0] == pos0 and rec[1] is None:
                first = _tag_end(data, pos0)   # <origin .../> ends there; else at </origin>
                rec[1] = first if data[first - 2:first] == b"/>" else _tag_end(data, pos)

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise ConfigError(f"the robot's URDF is not valid XML: {e}", source="URDF export") \
            from None
    missing = wanted - set(out)
    if missing:
        raise ConfigError(f"joint(s) {', '.join(sorted(missing))} not found in the URDF",
                          source="URDF export")
    return {k: tuple(v) for k, v in out.items()}


def calibrated_urdf(robot, xi) -> str:
    """The robot's own URDF text with its chain's joint origins calibrated (module doc)."""
    for i in range(1, robot.n_actuators + 1):
        k = float(xi[robot.index(f"k{i}")])
        if abs(k - 1.0) > 1e-12:
            raise ConfigError(f"joint {i} ({robot.joint_label(i)}): k{i} = {k:.12g} is not 1; "
                              f"URDF has no transmission ratio", source="URDF export")
    text = robot.spec.source["text"]
    origins = robot.calibrated_origins(xi)
    spans = joint_origin_spans(text, origins)
    data = text.encode("utf-8")
    edits = []
    originals = {jt.name: np.asarray(jt.origin, dtype=float) for jt in robot.spec.joints}
    for name, T in origins.items():
        if np.max(np.abs(T - originals[name])) <= UNCHANGED:
            continue             # not calibrated (or calibrated to its value): left as written
        s, e, ins = spans[name]
        elem = origin_element(T).encode("utf-8")
        edits.append((s, e, elem) if s is not None else (ins, ins, b"\n    " + elem))
    for s, e, new in sorted(edits, reverse=True):
        data = data[:s] + new + data[e:]
    return data.decode("utf-8")


def urdf_summary(robot, xi) -> dict:
    """What the parameter file states of a URDF robot: the chain, each movable joint's
    calibrated origin by name (xyz m, rpy rad), the instrument's frame (the base link
    in it)."""
    origins = robot.calibrated_origins(xi)
    F = robot.frame_matrix(xi)
    return {"base_link": robot.spec.base_link, "tip_link": robot.spec.tip_link,
            "joints": list(robot.spec.joint_names),
            "origins": {n: {"xyz": [float(v) + 0.0 for v in T[:3, 3]],
                            "rpy": [float(v) + 0.0 for v in rpy_exact(T[:3, :3])]}
                        for n, T in origins.items()},
            "measurement_frame": {"xyz": [float(v) for v in F[:3, 3]],
                                  "rpy": [float(v) for v in rpy_exact(F[:3, :3])],
                                  "statement": "the base link's pose in the instrument's frame "
                                               "(rpy: R = Rz(yaw) Ry(pitch) Rx(roll))"}}
