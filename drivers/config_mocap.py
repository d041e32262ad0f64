"""The station config's ``[mocap]`` section: a motion capture (QTM's real-time protocol,
:mod:`drivers.mocap`) measuring points on the tool.

::

    [mocap]
    host = "192.168.1.20"            # or "@endpoints"
    port = 22223                     # QTM's little-endian RT port (default; or "@endpoints")
    labels = ["tool_a", "tool_b", "tool_c"]   # QTM labels of the points on the tool, in order
    frames = 20                      # distinct frames averaged per reading (1..1000)
    timeout = 1.0                    # s one frame may take
    volume = { min = [-1.5, -1.5, 0.0], max = [1.5, 1.5, 2.0] }  # m, instrument frame
    viewpoint = [0.0, 0.0, 2.5]      # m, instrument frame: where the line of sight comes from
    view_angle_deg = 60              # largest angle between a point's outward direction and
                                     # its line of sight to the viewpoint
    outward = [[0, 0, 1], ...]       # optional, one 3-vector per label in the tip link frame
                                     # (default: each point's direction from the link's origin)

Parsed by :func:`_mocap` with :class:`~drivers.config_reader.KeyReader` (errors name the
file and the key path, ``mocap.labels[1]: expected a non-empty string``); builds on
:mod:`drivers.config_reader` only, so :mod:`drivers.config` can import it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from drivers.config_reader import MAX_TIMEOUT_S, KeyReader

DEFAULT_PORT = 22223
MAX_FRAMES = 1000

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class MocapConfig:
    """A motion capture (QTM) measuring the points on the tool.

    host, port:     QTM's real-time server (None while ``"@endpoints"``).
    labels:         QTM labels of the points on the tool, in the station's order (channels
                    ``m1_x .. mM_z`` follow it).
    frames:         distinct frames averaged per reading; timeout: s one frame may take.
    volume_min, volume_max: corners (m) of the measuring volume, instrument frame.
    viewpoint:      (m) where the lines of sight come from, instrument frame.
    view_angle_deg: largest angle (deg) between a point's outward direction and its line of
                    sight to the viewpoint at which the point is still seen.
    outward:        one 3-vector per label in the tip link frame, or None (each point's own
                    direction from the tip link's origin).
    """

    host: str | None
    labels: tuple[str, ...]
    volume_min: Vec3
    volume_max: Vec3
    port: int | None = DEFAULT_PORT
    frames: int = 20
    timeout: float = 1.0
    viewpoint: Vec3 = (0.0, 0.0, 0.0)
    view_angle_deg: float = 60.0
    outward: tuple[Vec3, ...] | None = None


def _mocap(r: KeyReader, unresolved: list[str]) -> MocapConfig:
    """The ``[mocap]`` table read by ``r``; ``unresolved`` gets the ``"@endpoints"`` keys."""
    # KeyReader's list reader: it has no public getter for a list of strings or of vectors
    labels = r._list("labels", None, None, False, lambda s, i: s.str(i))
    if labels is None:
        r.fail("labels", "missing required key")
    if not labels:
        r.fail("labels", "expected at least one label")
    twice = sorted({lab for lab in labels if labels.count(lab) > 1})
    if twice:
        r.fail("labels", f"labels must be distinct ({', '.join(map(repr, twice))} more than once)")
    vol = r.table("volume")
    lo = vol.float_list("min", length=3)
    hi = vol.float_list("max", length=3)
    if any(a >= b for a, b in zip(lo, hi)):
        vol.fail("max", f"every max must be above its min, got min {list(lo)}, max {list(hi)}")
    vol.finish()
    outward = r._list("outward", len(labels), None, False,
                      lambda s, i: s.float_list(i, length=3))
    if outward is not None:
        for i, v in enumerate(outward):
            if not math.hypot(*v) > 0:
                r.fail("outward", f"vector {i} ({labels[i]!r}) is zero: it has no direction")
    cfg = MocapConfig(
        host=r.str("host", placeholder=unresolved),
        port=r.int("port", default=DEFAULT_PORT, lo=1, hi=65535, placeholder=unresolved),
        labels=tuple(labels),
        frames=r.int("frames", default=20, lo=1, hi=MAX_FRAMES),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S),
        volume_min=tuple(lo), volume_max=tuple(hi),
        viewpoint=tuple(r.float_list("viewpoint", length=3, default=(0.0, 0.0, 0.0))),
        view_angle_deg=r.float("view_angle_deg", default=60.0, lo=0.0, lo_open=True, hi=180.0),
        outward=tuple(tuple(v) for v in outward) if outward is not None else None)
    r.finish()
    return cfg
