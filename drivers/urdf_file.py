"""URDF robots: a URDF file and the chain to calibrate in it, from ``--base-link`` to
``--tip-link`` (docs/urdf-robots.md), read into a :class:`calibration.robots.urdf.UrdfSpec`.

The URDF is parsed by ``yourdfpy`` (joint types, origins, axes, limits, the tree);
the text is first checked as XML by the standard library so that a malformed file
gets a one-line error with its line and column. The spec carries its own source
``{name, sha256, text, base_link, tip_link}``, which is what a trace's header stores
as ``robot_file`` (as it stores a robot file) and :func:`urdf_from_source` reads back.
"""
from __future__ import annotations

import hashlib
import io
import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from calibration.errors import ConfigError
from drivers.config_reader import read_text_file
from drivers.urdf_checks import check_urdf

MOVABLE = {"revolute": "R", "continuous": "R", "prismatic": "P"}


def is_urdf(robot: str) -> bool:
    """Whether a ``--robot`` value names a URDF file (a xacro file too: read as one, it is
    refused naming what to run first, :func:`drivers.urdf_checks.check_urdf`)."""
    return str(robot).lower().endswith((".urdf", ".xml", ".xacro"))


def _nested(T) -> tuple:
    return tuple(tuple(float(v) for v in row) for row in np.asarray(T, dtype=float))


def _names(items, limit: int = 12) -> str:
    items = list(items)
    text = ", ".join(items[:limit])
    return text + (f", ... ({len(items)} in all)" if len(items) > limit else "")


def _bodies(urdf, chain_joints, tip_link: str):
    """Per movable joint of the chain, the mass it carries up to the next one, lumped:
    ``(mass kg, centre of mass (3,) in the joint's child link frame)``. Everything below
    the joint's child link counts (fixed joints, and other branches with their movable
    joints at zero: a hand's fingers), except what hangs below the chain's next movable
    joint."""
    children: dict = {}
    for j in urdf.robot.joints:
        children.setdefault(j.parent, []).append(j)
    links = {lk.name: lk for lk in urdf.robot.links}
    movable = [j for j in chain_joints if j.type in MOVABLE]
    out = []
    for k, j in enumerate(movable):
        stop = movable[k + 1].name if k + 1 < len(movable) else None
        mass, moment = 0.0, np.zeros(3)
        todo = [(j.child, np.eye(4))]
        while todo:
            name, T = todo.pop()
            inertial = getattr(links.get(name), "inertial", None)
            if inertial is not None and inertial.mass:
                o = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin)
                mass += float(inertial.mass)
                moment += float(inertial.mass) * (T @ o)[:3, 3]
            for c in children.get(name, ()):
                if c.name == stop:
                    continue
                o = np.eye(4) if c.origin is None else np.asarray(c.origin, dtype=float)
                todo.append((c.child, T @ o))
        out.append((mass, moment / mass if mass > 0 else np.zeros(3)))
    return out


def parse_urdf(text: str, source: str, base_link: str | None, tip_link: str | None,
               name: str | None = None, *, compliance: bool = False, payload=None):
    """The :class:`UrdfSpec` of the chain from ``base_link`` to ``tip_link`` in the URDF
    ``text``; ``source`` names the file in errors, ``name`` (default its base name)
    becomes the source's name. ``compliance``: the model bends each joint under the
    gravity of what it carries (its link inertials, and ``payload`` ``{"mass": kg,
    "com": [x, y, z]}`` in the tip link's frame)."""
    from calibration.robots.urdf import UrdfJoint, UrdfSpec

    if not base_link or not tip_link:
        raise ConfigError("a URDF robot needs --base-link and --tip-link (the chain to "
                          "calibrate)", source=source)
    try:
        ET.fromstring(text)
    except ET.ParseError as e:
        line, col = e.position
        raise ConfigError(f"not valid XML at line {line}, column {col + 1}: "
                          f"{str(e).split(':')[0]}", source=source) from None
    check_urdf(text, source)          # the URDF specification's rules, before yourdfpy reads it
    import yourdfpy

    log = logging.getLogger("yourdfpy")
    level, log.level = log.level, logging.CRITICAL
    try:
        urdf = yourdfpy.URDF.load(io.BytesIO(text.encode("utf-8")), load_meshes=False,
                                  build_scene_graph=False, load_collision_meshes=False)
    except Exception as e:  # yourdfpy raises what its XML walk meets
        raise ConfigError(f"not a URDF yourdfpy can read: {type(e).__name__}: {e}",
                          source=source) from None
    finally:
        log.level = level
    links = [lk.name for lk in urdf.robot.links]
    for what, link in (("base link", base_link), ("tip link", tip_link)):
        if link not in links:
            raise ConfigError(f"{what} {link!r} is not a link of robot "
                              f"{urdf.robot.name!r} (links: {_names(links)})", source=source)
    by_child = {}
    for j in urdf.robot.joints:
        by_child[j.child] = j
    chain, link = [], tip_link
    while link != base_link:          # a tree (check_urdf): the walk ends
        j = by_child.get(link)
        if j is None:
            raise ConfigError(f"tip link {tip_link!r} is not below base link {base_link!r} in "
                              f"the URDF's tree", source=source)
        chain.append(j)
        link = j.parent
    chain.reverse()
    bodies = _bodies(urdf, chain, tip_link)
    joints, before = [], np.eye(4)
    for j in chain:
        where = f"joint {j.name!r}"
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
        if j.type == "fixed":
            before = before @ origin
            continue
        if j.type not in MOVABLE:
            raise ConfigError(f"{where} is {j.type}: the chain to calibrate takes revolute, "
                              f"continuous, prismatic and fixed joints", source=source)
        if j.mimic is not None:
            raise ConfigError(f"{where} mimics {j.mimic.joint!r}: a mimic joint in the chain "
                              f"to calibrate is not supported", source=source)
        axis = np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, float)
        norm = float(np.linalg.norm(axis))
        if not norm > 0 or not math.isfinite(norm):
            raise ConfigError(f"{where}: its axis {axis.tolist()} is not a direction",
                              source=source)
        continuous = j.type == "continuous"
        lim = j.limit
        if continuous or lim is None or lim.lower is None or lim.upper is None:
            if not continuous:
                raise ConfigError(f"{where} ({j.type}) has no <limit lower upper>",
                                  source=source)
            limits = (-math.pi, math.pi)
        else:
            limits = (float(lim.lower), float(lim.upper))
            if not limits[0] < limits[1]:
                raise ConfigError(f"{where}: limit lower {limits[0]:g} is not below upper "
                                  f"{limits[1]:g}", source=source)
        mass, com = bodies[len(joints)]
        joints.append(UrdfJoint(name=j.name, kind=MOVABLE[j.type], before=_nested(before @ origin),
                                origin=_nested(origin), axis=tuple(float(v) for v in axis / norm),
                                limits=limits, continuous=continuous, mass=mass,
                                com=tuple(float(v) for v in com)))
        before = np.eye(4)
    if not joints:
        raise ConfigError(f"no movable joint between {base_link!r} and {tip_link!r}",
                          source=source)
    src = {"name": name or Path(source).name,
           "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(), "text": text,
           "base_link": base_link, "tip_link": tip_link}
    pay = None
    if compliance:
        if not any(jt.mass > 0 for jt in joints) and not (payload and payload.get("mass")):
            raise ConfigError(f"compliance needs the links' masses: the URDF's chain "
                              f"{base_link} -> {tip_link} has no <inertial> (state a payload, "
                              f"or calibrate without compliance)", source=source)
        src["compliance"] = True
        if payload:
            pay = _payload(payload, source)
            src["payload"] = {"mass": pay[0], "com": list(pay[1])}
    robot_name = urdf.robot.name or Path(src["name"]).stem
    if robot_name in ("agebot-sm", "agebot-pm"):
        robot_name += "-urdf"
    return UrdfSpec(name=robot_name, base_link=base_link, tip_link=tip_link,
                    joints=tuple(joints), tail=_nested(before), source=src,
                    compliance=compliance, payload=pay)


def _payload(p, source):
    """``(mass, com)`` of a payload ``{"mass": kg, "com": [x, y, z]}`` (tip link frame)."""
    try:
        mass = float(p.get("mass", 0.0))
        com = tuple(float(v) for v in (p.get("com") or (0.0, 0.0, 0.0)))
    except (TypeError, ValueError, AttributeError):
        raise ConfigError(f"payload must be {{mass: kg, com: [x, y, z] m}}, not {p!r}"[:200],
                          source=source) from None
    if len(com) != 3 or not all(math.isfinite(v) for v in (mass, *com)) or not 0 <= mass < 1e4:
        raise ConfigError("payload: a mass of 0 to 10 000 kg and a centre of mass of three "
                          "finite coordinates (m, the tip link's frame)", source=source)
    return mass, com


def load_urdf(path, base_link: str | None, tip_link: str | None):
    """Read and parse a URDF file; errors name the file."""
    path = str(path)
    return parse_urdf(read_text_file(path, "the URDF"), path, base_link, tip_link)


def urdf_from_source(src: dict, where: str):
    """The spec of a trace header's ``robot_file`` of a URDF robot (checksum checked
    by the caller); ``compliance`` and ``payload`` there choose the compliant model."""
    return parse_urdf(src["text"], f"{where} ({src.get('name', '?')})", src.get("base_link"),
                      src.get("tip_link"), name=str(src.get("name") or "robot.urdf"),
                      compliance=bool(src.get("compliance")), payload=src.get("payload"))
