"""One unit policy for people: lengths in mm and angles in degrees by default (or as
the station config's ``[display]`` table says), SI in every file.

Every number the station shows an operator (console pose lines, report tables, the
wizard, fault messages) goes through :class:`Units`; files (traces, parameter files)
keep SI. A value is given with its SI unit (``"m"``, ``"rad"``, ``"m/u"``, ``"m²"``
...) and comes back converted and labelled::

    >>> MM_DEG.text(0.00228, "m")
    '2.28 mm'
    >>> MM_DEG.text(0.5, "rad", ".3g")
    '28.6°'

Units without a display rule (actuator units ``u``, ``1/m``, ``1``) are shown as they
are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

# display length unit -> factor from metres
LENGTHS = {"m": 1.0, "cm": 1e2, "mm": 1e3, "um": 1e6}
# display angle unit -> (label, factor from radians)
ANGLES = {"rad": ("rad", 1.0), "mrad": ("mrad", 1e3), "deg": ("\u00b0", 180.0 / math.pi)}
LABEL = {"um": "\u00b5m"}

# SI unit of a reading or residual channel (the trace's channels)
CHANNEL_SI = {"distance": "m", "tilt": "rad", "x": "m", "y": "m", "z": "m", "phi": "rad",
              "alpha": "rad", "beta": "rad", "gamma": "rad", "roll": "rad", "pitch": "rad",
              "yaw": "rad",
              "dx": "m", "dy": "m", "plane": "1", "q1": "u", "q2": "u", "q3": "u"}


def channel_si(channel: str) -> str:
    """The SI unit of a channel (``qmN`` and ``qN``: actuator units ``u``)."""
    if channel in CHANNEL_SI:
        return CHANNEL_SI[channel]
    if channel[:2] == "qm" and channel[2:].isdigit():
        return "u"
    if channel[:1] == "m" and channel[-2:] in ("_x", "_y", "_z") and channel[1:-2].isdigit():
        return "m"              # a point on the tool (the motion capture's m1_x, ...)
    return ""


def unsigned_zero(text: str) -> str:
    """A formatted number that reads as zero, without a sign: ``-0`` and ``-0.000`` are
    ``0`` and ``0.000`` (a round-off below the shown digits has no sign worth showing)."""
    if text.startswith("-"):
        try:
            if float(text) == 0:
                return text[1:]
        except ValueError:
            pass
    return text


@dataclass(frozen=True)
class Units:
    """How numbers are shown to people: ``length`` one of :data:`LENGTHS`, ``angle``
    one of :data:`ANGLES`."""

    length: str = "mm"
    angle: str = "deg"

    def __post_init__(self):
        if self.length not in LENGTHS:
            raise ValueError(f"length unit {self.length!r}: expected one of {', '.join(LENGTHS)}")
        if self.angle not in ANGLES:
            raise ValueError(f"angle unit {self.angle!r}: expected one of {', '.join(ANGLES)}")

    def unit(self, si: str) -> tuple[str, float]:
        """(display label, factor) for a value in the SI unit ``si``: display = SI * factor.
        Handles m, rad, m², and per-unit forms ``m/u``, ``rad/u``."""
        base, sep, rest = si.partition("/")
        if base == "m\u00b2":
            f = LENGTHS[self.length]
            return LABEL.get(self.length, self.length) + "\u00b2" + sep + rest, f * f
        if base == "m":
            return LABEL.get(self.length, self.length) + sep + rest, LENGTHS[self.length]
        if base == "rad":
            label, f = ANGLES[self.angle]
            return label + sep + rest, f
        return si, 1.0

    def label(self, si: str) -> str:
        """The display unit of the SI unit ``si``."""
        return self.unit(si)[0]

    def value(self, v, si: str) -> float:
        """``v`` (SI) in the display unit."""
        return float(v) * self.unit(si)[1]

    def to_si(self, v, si: str) -> float:
        """A value typed in the display unit, back to SI."""
        return float(v) / self.unit(si)[1]

    def number(self, v, si: str, fmt: str = ".4g") -> str:
        """The number only, converted and formatted (``–`` for None/NaN)."""
        if v is None or isinstance(v, bool):
            return "\u2013"
        try:
            x = self.value(v, si)
        except (TypeError, ValueError):
            return str(v)
        return unsigned_zero(format(x, fmt)) if math.isfinite(x) else "\u2013"

    def text(self, v, si: str, fmt: str = ".4g") -> str:
        """Number and unit: ``'2.28 mm'``, ``'28.6°'`` (no space before the degree sign)."""
        n = self.number(v, si, fmt)
        label = self.label(si)
        if not label or label == "1" or n == "\u2013":
            return n
        return n + label if label.startswith("\u00b0") else f"{n} {label}"

    def channel(self, name: str, v, fmt: str = ".4g") -> str:
        """A channel's reading for people: ``'distance 365.4 mm'``, ``'qm1 22.09 u'``."""
        return f"{name} {self.text(v, channel_si(name), fmt)}"

    def vector(self, values, si: str, fmt: str = ".4g") -> str:
        """``[1.2, 3.4] mm``."""
        label = self.label(si)
        body = ", ".join(self.number(v, si, fmt) for v in values)
        return f"[{body}]" + (f" {label}" if label and label != "1" else "")


MM_DEG = Units()
SI = Units("m", "rad")


# units of the parameters (SI, as in the parameter file)
PARAM_UNITS = {
    "agebot-sm": {"q1_off": "m", "q2_off": "rad", "q3_off": "rad", "q4_off": "rad",
                  "k1": "m/u", "k2": "rad/u", "k3": "rad/u", "k4": "rad/u",
                  "L2": "m", "L3": "m", "L4": "m", "theta0": "rad", "a0": "m",
                  "plane_a": "1/m", "plane_b": "1/m", "plane_c": "1/m", "distance_off": "m"},
    "agebot-pm": {"a1": "m", "a2": "m", "l": "m", "v": "m",
                  "q1_off": "m", "q2_off": "m", "q3_off": "m",
                  "k1": "m/u", "k2": "m/u", "k3": "m/u", "mount_x": "rad", "mount_y": "rad"},
}


def param_units(trace) -> dict:
    """Units of a trace's parameters: the built-ins' table, or a robot file's by
    the spec's naming (lengths m, angles rad, a joint's offset and ratio by its type)."""
    model = trace.robot_model() if hasattr(trace, "robot_model") else None
    spec = getattr(model, "spec", None)
    if spec is None:
        return PARAM_UNITS.get(str(trace.header.get("robot", "")), {})
    if hasattr(model, "frame_matrix"):
        return urdf_param_units(model, trace)
    out = {"mount_x": "rad", "mount_y": "rad", "distance_off": "m",
           "plane_a": "1/m", "plane_b": "1/m", "plane_c": "1/m"}
    for name in model.param_names:
        key = name.split("_")[-1].rstrip("0123456789")
        out[name] = "rad" if key in ("theta", "alpha", "beta", "gamma") else "m"
    for i, jt in enumerate(spec.joints, start=1):
        q = "rad" if jt.kind == "R" else "m"
        out[f"q{i}_off"], out[f"k{i}"] = q, f"{q}/u"
    return out


def urdf_param_units(model, trace) -> dict:
    """A URDF robot's parameters (calibration.robots.urdf): positions m, rotations rad,
    a joint's zero by its type, its ratio dimensionless (a URDF's joint values are SI:
    the ratio is 1, held), compliances rad/(N m) or m/N, the points on the tool m."""
    out = {}
    for name in model.param_names:
        key = name.rsplit("_", 1)[-1]
        out[name] = "rad" if key in ("roll", "pitch", "yaw", "rx", "ry", "rz") else "m"
    for i, jt in enumerate(model.spec.joints, start=1):
        out[f"q{i}_off"] = "rad" if jt.kind == "R" else "m"
        out[f"k{i}"] = "1"
        out[f"c{i}"] = "rad/(N m)" if jt.kind == "R" else "m/N"
    for k in range(1, int(trace.header.get("markers") or 0) + 1):
        for a in "xyz":
            out[f"marker{k}_{a}"] = "m"
    return out


def from_config(config) -> Units:
    """The units of a station config's ``[display]`` table (mm and degrees without one)."""
    display = getattr(config, "display", None)
    if display is None:
        return MM_DEG
    return Units(display.length, display.angle)


def describe_error(error, units: Units = MM_DEG) -> str:
    """The text of a device error for people: a snapshot's stability violations get
    their units (``draw-wire: unstable reading: draw-wire channel 'distance': drift
    2.28 mm exceeds the limit 2.00 mm``); anything else is
    ``str(error)``."""
    violations = getattr(error, "violations", None)
    if not violations:
        return str(error)
    parts = []
    for v in violations:
        si = channel_si(v.channel)
        parts.append(f"{v.device} channel {v.channel!r}: {v.kind} {units.text(v.value, si, '#.3g')} "
                     f"exceeds the limit {units.text(v.limit, si, '#.3g')}")
    device = getattr(error, "device", None)
    return (f"{device}: " if device else "") + "unstable reading: " + "; ".join(parts)


def target_coords(robot) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``(names, SI units)`` of a planned pose's target for ``robot``'s model: AGEBOT's
    arm x, y, z, phi; a robot file's tool x, y, z, roll, pitch, yaw; the wrist's
    orientation alpha, beta, gamma."""
    if robot.name == "agebot-sm":
        return ("x", "y", "z", "phi"), ("m", "m", "m", "rad")
    if robot.kind == "serial":
        return tuple(robot.coords), ("m", "m", "m", "rad", "rad", "rad")
    return ("alpha", "beta", "gamma"), ("rad",) * 3
