"""Robot files: TOML, ``format = "calstation-robot"``, ``version = 1``
(docs/robot-files.md, "The file format").

:func:`load_robot_file` reads one into a :class:`calibration.robots.serial.SerialSpec`
that carries its own source (``{name, sha256, text}``), which is what a trace's
header stores as ``robot_file`` and :func:`spec_from_source` reads back. Every
error is a one-line :class:`ConfigError` naming the file, the key and what is
wrong; unknown keys are errors. Below both the station and the simulator (truth
files of a robot file name one).
"""
from __future__ import annotations

import hashlib
import math
import re
from pathlib import Path

from calibration.errors import ConfigError
from calibration.robots.serial import FRAME_KEYS, JointSpec, SerialSpec, param_layout
from drivers.config_reader import KeyReader, parse_toml, read_text_file

FORMAT = "calstation-robot"
VERSION = 1
# an R joint's angle at its limits beyond two turns each way (and a little): written in
# degrees (a real joint turns at most +-720 deg, e.g. a wrist's last axis)
MAX_TURN_RAD = 4 * math.pi * 1.01


def _num(v: float) -> str:
    return f"{v:g}"


#: the largest length (m) and angle (rad) a robot file may give, and the range of a
#: transmission ratio and of an actuator limit: far beyond any arm, and far below what
#: overflows the planner's arithmetic (a value of 1e308 is a typing slip, not a robot)
MAX_LENGTH_M = 1e3
MAX_ANGLE_RAD = 1e3
K_RANGE = (1e-12, 1e9)
MAX_LIMIT = 1e12
LENGTHS = ("d", "a", "b")            # of a frame's FRAME_KEYS and a joint's keys; the rest
                                     # are angles (a P joint's offset is a length)


def _bounded(r: KeyReader, key: str, default, length: bool):
    big = MAX_LENGTH_M if length else MAX_ANGLE_RAD
    return r.float(key, default=default, lo=-big, hi=big)


def _frame(top: KeyReader, key: str) -> tuple[float, ...]:
    t = top.table(key, required=False)
    if t is None:
        return (0.0,) * 6
    out = tuple(_bounded(t, k, 0.0, k in LENGTHS) for k in FRAME_KEYS)
    t.finish()
    return out


def _joint(j: KeyReader, i: int) -> JointSpec:
    kind = j.choice("type", ("R", "P"))
    if kind == "P" and "d" in j.data:
        j.fail("d", "a P joint has no 'd' (its d is the joint coordinate: k * qm + offset)")
    if "beta" in j.data:
        if kind == "P":
            j.fail("beta", "Hayati's beta is for R joints only")
        if "d" in j.data:
            j.fail("beta", "a joint with Hayati's beta has no 'd' (give either d or beta)")
    if kind == "R" and "theta" in j.data:
        j.fail("theta", "an R joint has no 'theta' (its theta is k * qm + offset; use 'offset')")
    d = _bounded(j, "d", 0.0, True) if kind == "R" else 0.0
    theta = _bounded(j, "theta", 0.0, False) if kind == "P" else 0.0
    beta = _bounded(j, "beta", None, False)
    k = j.float("k", default=1.0)
    if k == 0.0:
        j.fail("k", "a transmission ratio of 0 would freeze the joint")
    if not K_RANGE[0] <= abs(k) <= K_RANGE[1]:
        j.fail("k", f"{k!r}: a transmission ratio's size is between {K_RANGE[0]:g} and "
                    f"{K_RANGE[1]:g} (joint units per actuator unit)")
    lim = j.float_list("limits", length=2)
    if not lim[0] < lim[1]:
        j.fail("limits", f"[lo, hi] needs lo < hi, got {list(lim)}")
    if max(abs(lim[0]), abs(lim[1])) > MAX_LIMIT:
        j.fail("limits", f"{list(lim)}: actuator limits are within +-{MAX_LIMIT:g} (actuator "
                         "units)")
    offset = _bounded(j, "offset", 0.0, kind == "P")
    if kind == "R" and max(abs(k * v + offset) for v in lim) > MAX_TURN_RAD:
        rad = ", ".join(f"{math.radians(v):.4g}" for v in lim)
        j.fail("limits", f"{_num(lim[0])}, {_num(lim[1])} look like degrees: an R joint's "
                         f"limits are actuator values qm, its angle k * qm + offset in rad "
                         f"(here up to {max(abs(k * v + offset) for v in lim):.4g} rad, more "
                         f"than two turns); in radians: [{rad}]")
    spec = JointSpec(kind=kind, d=d, theta=theta, a=_bounded(j, "a", 0.0, True),
                     alpha=_bounded(j, "alpha", 0.0, False), beta=beta, k=k,
                     offset=offset, limits=tuple(lim))
    j.finish()
    return spec


def parse_robot_file(text: str, source: str = "<robot file>", name: str | None = None) -> SerialSpec:
    """A :class:`SerialSpec` from the TOML ``text``; ``source`` names it in errors;
    ``name`` (default: the base name of ``source``) becomes the source's name."""
    text = text.removeprefix("\ufeff")      # an editor's UTF-8 mark
    data = parse_toml(text, source)
    top = KeyReader(data, "", source)
    if data.get("format") != FORMAT:
        top.fail("format", f"must be {FORMAT!r}, not {data.get('format')!r}")
    top.str("format")
    if top.int("version") != VERSION:
        top.fail("version", f"unsupported version {data['version']!r} (this reader knows {VERSION})")
    robot_name = top.str("name")
    if not robot_name.isprintable() or robot_name != robot_name.strip() or len(robot_name) > 200:
        top.fail("name", f"{robot_name[:60]!r}: a robot's name is one line of printable "
                         "text without leading or trailing spaces, at most 200 characters")
    if robot_name in ("agebot-sm", "agebot-pm"):
        top.fail("name", f"{robot_name!r} is a built-in robot; give the file's robot another name")
    raw = data.get("joint")
    if not isinstance(raw, list) or not raw:
        top.fail("joint", "needs at least one [[joint]] table")
    top._used.add("joint")
    joints = tuple(_joint(KeyReader(t, f"joint[{i}]", source), i)
                   for i, t in enumerate(raw, start=1))
    base, tool = _frame(top, "base"), _frame(top, "tool")
    fixed = top._list("fixed", None, (), False, lambda s, i: s.str(i))
    spec = SerialSpec(name=robot_name, joints=joints, base=base, tool=tool, fixed=tuple(fixed),
                      source={"name": name or Path(source).name,
                              "sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
                              "text": text})
    known = [n for n, _ in param_layout(spec)]
    for f in spec.fixed:
        if f not in known:
            top.fail("fixed", f"unknown parameter {f!r} (known: {', '.join(known)})")
    top.finish()
    return spec


def urdf_ref(path, base_link: str | None, tip_link: str | None) -> str:
    """The station's name of a URDF robot: the file and the chain in it,
    ``"arm.urdf (base_link to tool0)"``. It goes wherever a robot file's path goes
    (``--robot``, the simulator's command line, messages), and :func:`load_robot_file`
    reads it back; refused in one line where a link is not given."""
    if not base_link or not tip_link:
        raise ConfigError("a URDF robot needs --base-link and --tip-link (the chain to "
                          "calibrate)", source=str(path))
    return f"{path} ({base_link} to {tip_link})"


_REF = re.compile(r"^(?P<path>.+\.(?:urdf|xml|xacro)) \((?P<base>\S+) to (?P<tip>\S+)\)$",
                  re.IGNORECASE)


def split_urdf_ref(robot) -> tuple[str, str, str] | None:
    """``(path, base_link, tip_link)`` of a :func:`urdf_ref`, else None."""
    m = _REF.match(str(robot))
    return (m["path"], m["base"], m["tip"]) if m else None


def robot_args(robot: str) -> list[str]:
    """The command-line options that name ``robot`` (a URDF's :func:`urdf_ref`:
    ``--robot PATH --base-link B --tip-link T``)."""
    ref = split_urdf_ref(robot)
    if ref is None:
        return ["--robot", str(robot)]
    return ["--robot", ref[0], "--base-link", ref[1], "--tip-link", ref[2]]


def robot_ref(robot: str, base_link: str | None = None, tip_link: str | None = None) -> str:
    """``--robot`` with ``--base-link``/``--tip-link`` as the station names the robot: a
    URDF's :func:`urdf_ref`, anything else as given (links given with a robot that is not a
    URDF: refused in one line)."""
    from drivers.urdf_file import is_urdf

    if split_urdf_ref(robot) is not None:
        if base_link or tip_link:
            raise ConfigError("the robot names its chain already; leave out --base-link and "
                              "--tip-link", source=str(robot))
        return robot
    if is_urdf(robot):
        return urdf_ref(robot, base_link, tip_link)
    if base_link or tip_link:
        raise ConfigError("--base-link and --tip-link choose the chain of a URDF robot; this "
                          "robot is not a URDF", source=str(robot))
    return robot


def load_robot_file(path):
    """Read and parse a robot file (a :class:`SerialSpec`) or a URDF robot's
    :func:`urdf_ref` (a :class:`calibration.robots.urdf.UrdfSpec`); errors name the file."""
    path = str(path)
    ref = split_urdf_ref(path)
    if ref is not None:
        from drivers.urdf_file import load_urdf

        return load_urdf(*ref)
    from drivers.urdf_file import is_urdf

    if is_urdf(path):
        raise ConfigError("a URDF robot needs --base-link and --tip-link (the chain to "
                          "calibrate)", source=path)
    return parse_robot_file(read_text_file(path, "the robot file"), path)


def spec_from_source(src, where: str = "robot_file"):
    """The spec of a trace header's ``robot_file`` object ``{name, sha256, text}``
    (a URDF robot's also ``base_link``, ``tip_link``: a
    :class:`calibration.robots.urdf.UrdfSpec`); the checksum must match the text."""
    if not isinstance(src, dict) or not isinstance(src.get("text"), str):
        raise ConfigError("must be an object with the robot file's name, sha256 and text",
                          source=where)
    digest = hashlib.sha256(src["text"].encode("utf-8")).hexdigest()
    if src.get("sha256") != digest:
        raise ConfigError("sha256 does not match the robot file's text (damaged or edited)",
                          source=where)
    if "base_link" in src or str(src.get("name", "")).lower().endswith(".urdf"):
        from drivers.urdf_file import urdf_from_source

        return urdf_from_source(src, where)
    return parse_robot_file(src["text"], f"{where} ({src.get('name', '?')})",
                            name=str(src.get("name") or "robot.toml"))


def is_robot_file(robot: str) -> bool:
    """Whether a ``--robot`` value names a robot file or a URDF robot (not a built-in robot)."""
    return (robot.endswith(".toml") or split_urdf_ref(robot) is not None
            or Path(robot).is_file())


def format_float(v: float) -> str:
    """A TOML float that reads back to the same double."""
    if not math.isfinite(v):
        raise ValueError(f"not a finite number: {v!r}")
    r = repr(float(v))
    return r if ("." in r or "e" in r) else r + ".0"
