"""A URDF checked as the URDF specification writes it, before anything uses it.

``yourdfpy`` reads what it is given: two joints of one name both, the first of two
``<origin>`` elements, a joint cycle (which a walk up from the tip then never leaves),
``nan`` in an origin. :func:`check_urdf` refuses each of these first, in one line naming
the element's line, and what the file is where it is not a URDF at all (an unexpanded
xacro, an SDF):

* the root is ``<robot name="...">``; no ``${...}`` or ``$(...)`` left of a xacro;
* every link and every joint has a name, unique among the links (joints);
* a joint has a known ``type``, exactly one ``<parent link>`` and one ``<child link>``
  naming links of the file (not the same one), at most one ``<origin>``, ``<axis>``,
  ``<limit>``, ``<mimic>``; every number in them (``xyz``, ``rpy``, the limits) finite,
  ``xyz`` and ``rpy`` three of them, a moving joint's axis not zero;
* the joints make a tree: no link is the child of two joints, and no chain of parents
  comes back to where it started (a cycle, named with its joints);
* an ``<inertial>``'s ``<mass value>`` is a finite number of at least 0.
"""
from __future__ import annotations

import math

from calibration.errors import ConfigError

JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")
ONCE = ("origin", "axis", "limit", "mimic", "parent", "child")


def _fail(source: str, line, text: str):
    where = f"line {line}: " if line else ""
    raise ConfigError(where + text, source=source)


def _numbers(el, attr: str, count: int | None, source: str, what: str) -> list[float] | None:
    """The attribute's numbers (None where it is absent), each finite, ``count`` of them."""
    raw = el.get(attr)
    if raw is None:
        return None
    try:
        vals = [float(v) for v in raw.split()]
    except ValueError:
        _fail(source, el.sourceline, f"{what} {attr}={raw!r} is not {count or 'a'} number(s)")
    if count is not None and len(vals) != count:
        _fail(source, el.sourceline, f"{what} {attr}={raw!r} has {len(vals)} number(s), the "
              f"URDF takes {count}")
    if not all(math.isfinite(v) for v in vals):
        _fail(source, el.sourceline, f"{what} {attr}={raw!r} is not finite")
    return vals


def check_urdf(text: str, source: str) -> None:
    """Raise :class:`ConfigError` (one line: the file, the element's line, what is wrong
    and what to do) where ``text`` is not a URDF the chain can be read from (module
    docstring). ``text`` has passed the standard library's XML parser already."""
    from lxml import etree

    parser = etree.XMLParser(resolve_entities=False, no_network=True, huge_tree=False,
                             remove_comments=True)
    root = etree.fromstring(text.encode("utf-8"), parser)
    if root.tag == "sdf" or text.lstrip().startswith("<sdf"):
        _fail(source, root.sourceline, "an SDF file (Gazebo's format), not a URDF: give the "
              "robot's URDF (or convert the SDF to one)")
    xacro = "xacro" in (root.nsmap or {}) or any(
        "${" in v or "$(" in v for el in root.iter() if isinstance(el.tag, str)
        for v in el.attrib.values())
    if xacro or any(isinstance(el.tag, str) and el.tag.startswith("{") and "xacro" in el.tag
                    for el in root.iter()):
        _fail(source, None, "an unexpanded xacro file: run `xacro FILE > robot.urdf` (ROS's "
              "xacro) and give the URDF it writes")
    if root.tag != "robot":
        _fail(source, root.sourceline, f"the root element is <{root.tag}>, a URDF's is <robot>")
    if not root.get("name"):
        _fail(source, root.sourceline, "<robot> has no name attribute (the URDF "
              "specification requires one)")
    links: dict[str, int] = {}
    for lk in root.findall("link"):
        name = lk.get("name")
        if not name:
            _fail(source, lk.sourceline, "a <link> has no name")
        if name in links:
            _fail(source, lk.sourceline, f"link {name!r} is named twice (also line "
                  f"{links[name]}): link names must be unique")
        links[name] = lk.sourceline
        for m in lk.findall("inertial/mass"):
            vals = _numbers(m, "value", 1, source, f"link {name!r} mass")
            if vals is not None and vals[0] < 0:
                _fail(source, m.sourceline, f"link {name!r} has a negative mass {vals[0]:g} kg")
    joints: dict[str, int] = {}
    parent_of: dict[str, tuple[str, str]] = {}      # child link -> (joint, parent link)
    for j in root.findall("joint"):
        name, line = j.get("name"), j.sourceline
        if not name:
            _fail(source, line, "a <joint> has no name")
        if name in joints:
            _fail(source, line, f"joint {name!r} is named twice (also line {joints[name]}): "
                  "joint names must be unique")
        joints[name] = line
        what = f"joint {name!r}"
        if j.get("type") not in JOINT_TYPES:
            _fail(source, line, f"{what} has type {j.get('type')!r}, not one of "
                  f"{', '.join(JOINT_TYPES)}")
        for tag in ONCE:
            found = j.findall(tag)
            if len(found) > 1:
                _fail(source, found[1].sourceline, f"{what} has {len(found)} <{tag}> "
                      "elements: a joint has at most one (the URDF specification)")
        ends = {}
        for tag in ("parent", "child"):
            el = j.find(tag)
            link = None if el is None else el.get("link")
            if not link:
                _fail(source, line, f"{what} has no <{tag} link=...>")
            if link not in links:
                _fail(source, el.sourceline, f"{what}'s {tag} link {link!r} is not a link of "
                      "the file")
            ends[tag] = link
        if ends["parent"] == ends["child"]:
            _fail(source, line, f"{what} has link {ends['child']!r} as both its parent and "
                  "its child")
        if ends["child"] in parent_of:
            other = parent_of[ends["child"]][0]
            _fail(source, line, f"link {ends['child']!r} is the child of two joints, "
                  f"{other!r} and {name!r}: the joints of a URDF make a tree")
        parent_of[ends["child"]] = (name, ends["parent"])
        origin = j.find("origin")
        if origin is not None:
            _numbers(origin, "xyz", 3, source, f"{what} <origin>")
            _numbers(origin, "rpy", 3, source, f"{what} <origin>")
        axis = j.find("axis")
        if axis is not None:
            xyz = _numbers(axis, "xyz", 3, source, f"{what} <axis>")
            # (a fixed or floating joint has no axis: the specification ignores one there,
            # and real files carry "0 0 0": TIAGo's torso_fixed_joint)
            if xyz is not None and not any(xyz) and j.get("type") not in ("fixed", "floating"):
                _fail(source, axis.sourceline, f"{what} <axis xyz> is zero: not a direction")
        limit = j.find("limit")
        if limit is not None:
            for attr in ("lower", "upper", "effort", "velocity"):
                _numbers(limit, attr, 1, source, f"{what} <limit>")
    rooted: set[str] = set()                     # links whose walk up ends at a root
    for start in parent_of:                      # a tree: every walk up ends at a root
        seen, path, link = [], [], start
        while link in parent_of and link not in rooted:
            joint, parent = parent_of[link]
            if joint in seen:
                cycle = seen[seen.index(joint):]
                _fail(source, joints[joint], f"the joints {' -> '.join(cycle)} make a cycle: "
                      "the joints of a URDF make a tree")
            seen.append(joint)
            path.append(link)
            link = parent
        rooted.update(path)
