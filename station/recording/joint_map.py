"""Joint values as a controller prints them (docs/urdf-robots.md, "Joint maps").

Controllers count joints their own way: degrees, signs, zeros, and on some arms a
coupling (FANUC's J3 is counted from the horizontal, so the URDF's ``joint_3`` is
``J3 + J2``, the ROS-Industrial driver's ``J23_factor``). A joint map says, per URDF
joint, how its value follows from the CSV's columns::

    format = "calstation-joint-map"
    version = 1

    [[joint]]
    urdf = "joint_2"          # a movable joint of the chain (its URDF name)
    column = "J2"             # its value is this column ...
    scale = -1.0              # ... times this (default 1) ...
    offset = 90.0             # ... plus this, in the column's unit (default 0)

    [[joint]]
    urdf = "joint_3"
    terms = { J2 = 1.0, J3 = 1.0 }   # or a linear combination of columns
    offset = 0.0

URDF value = ``sum(coefficient * column) + offset``, in the CSV's unit, then
converted to SI (``--angle-unit`` for a revolute joint, ``--length-unit`` for a
prismatic one); a joint the map does not name is read from the column named as
the joint (or ``qm{i}``). The map's text and checksum are recorded in the trace.
"""
from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

from calibration.errors import ConfigError
from drivers.config_reader import KeyReader, read_text_file

FORMAT = "calstation-joint-map"
VERSION = 1


@dataclass(frozen=True)
class JointMap:
    """``terms``: URDF joint name -> ``((column, coefficient), ...)``; ``offsets``:
    URDF joint name -> offset (CSV units); ``source``: ``{name, sha256, text}``."""

    terms: dict
    offsets: dict
    source: dict

    @property
    def columns(self) -> set[str]:
        return {c for ts in self.terms.values() for c, _ in ts}

    def value(self, joint: str, row: dict) -> float:
        """The URDF joint's value from ``row`` (column -> number, CSV units)."""
        return sum(k * row[c] for c, k in self.terms[joint]) + self.offsets[joint]


def _number(t: KeyReader, key: str, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        t.fail(key, f"expected a finite number, got {v!r}")
    return float(v)


def parse_joint_map(text: str, source: str, joints: tuple[str, ...]) -> JointMap:
    """A :class:`JointMap` for the chain's movable ``joints`` (their URDF names)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"not valid TOML: {e}", source=source) from None
    except RecursionError:
        raise ConfigError("not valid TOML: nested too deeply", source=source) from None
    top = KeyReader(data, "", source)
    if data.get("format") != FORMAT:
        top.fail("format", f"must be {FORMAT!r}, not {data.get('format')!r}")
    top.str("format")
    if top.int("version") != VERSION:
        top.fail("version", f"unsupported version {data.get('version')!r} (this reader knows "
                            f"{VERSION})")
    raw = data.get("joint")
    top._used.add("joint")
    if not isinstance(raw, list) or not raw:
        top.fail("joint", "needs at least one [[joint]] table")
    terms, offsets = {}, {}
    for i, tab in enumerate(raw, start=1):
        t = KeyReader(tab, f"joint[{i}]", source)
        name = t.str("urdf")
        if name not in joints:
            t.fail("urdf", f"{name!r} is not a movable joint of the chain (joints: "
                           f"{', '.join(joints)})")
        if name in terms:
            t.fail("urdf", f"{name!r} is mapped twice")
        if ("column" in t.data) == ("terms" in t.data):
            t.fail("column", "give either 'column' (with an optional 'scale') or 'terms'")
        if "column" in t.data:
            scale = _number(t, "scale", t.data.get("scale", 1.0))
            t._used.add("scale")
            ts = ((t.str("column"), scale),)
        else:
            if "scale" in t.data:
                t.fail("scale", "'scale' goes with 'column'; 'terms' give each coefficient")
            tt = t.data["terms"]
            t._used.add("terms")
            if not isinstance(tt, dict) or not tt:
                t.fail("terms", "expected a table of column = coefficient")
            ts = tuple((str(c), _number(t, f"terms.{c}", k)) for c, k in tt.items())
        if all(k == 0.0 for _c, k in ts):
            t.fail("terms" if "terms" in t.data else "scale",
                   "every coefficient is 0: the joint would not move")
        terms[name] = ts
        offsets[name] = _number(t, "offset", t.data.get("offset", 0.0))
        t._used.add("offset")
        t.finish()
    top.finish()
    src = {"name": Path(source).name, "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
           "text": text}
    return JointMap(terms, offsets, src)


def load_joint_map(path, joints: tuple[str, ...]) -> JointMap:
    path = str(path)
    return parse_joint_map(read_text_file(path, "the joint map"), path, joints)
