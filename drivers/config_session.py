"""The station config's sections that shape a session rather than a device: how one pose
is measured, the safety envelope, riding out a device's trouble and the units shown,
each a frozen dataclass and its reader.

::

    [snapshot]       samples, period, settle, timeout
    [snapshot.std_limits] / [snapshot.drift_limits] / [snapshot.noise_floor]
                     channel = limit (the key qm covers every qmN)
    [envelope]       qm_min, qm_max (per actuator): the range the station may command
                     (the wrist's slider stroke), actuator units; poll, latency;
                     [envelope.tolerance] channel = value (the live watch)
    [session]        retry_window: s a failing pose is retried before its device is
                     judged gone (0: three retries)
    [display]        length, angle: the units of the numbers shown to people

Parsed by :func:`_snapshot`, :func:`_envelope`, :func:`_session` and :func:`_display`
with :class:`~drivers.config_reader.KeyReader` (errors name the file and the key path).
Builds on :mod:`drivers.config_reader` only, so :mod:`drivers.config` (the whole station
config, which re-exports these names) can import it. Units: SI, radians, seconds.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from drivers.config_reader import MAX_PERIOD_S, MAX_TIMEOUT_S, KeyReader, frozen_map

LIMIT_CHANNEL = re.compile(r"^(qm[0-9]*|tilt|roll|pitch|yaw|distance)$")

# units the operator reads (station/outputs/units.py); files stay SI
DISPLAY_LENGTHS = ("mm", "m", "cm", "um")
DISPLAY_ANGLES = ("deg", "rad", "mrad")


@dataclass(frozen=True)
class DisplayConfig:
    """``[display]``: the units of the numbers shown to people (mm and degrees by
    default); traces and parameter files are SI whatever this says."""

    length: str = "mm"
    angle: str = "deg"


@dataclass(frozen=True)
class SnapshotConfig:
    """How one pose is measured (see :mod:`drivers.snapshot`).

    samples: readings per channel; period: s between them; settle: s to wait after
    the motion; timeout: s per device read. ``std_limits``/``drift_limits``/``noise_floor``:
    channel -> limit in the channel's unit; the key ``qm`` covers every ``qmN``.
    """

    samples: int = 10
    period: float = 0.02
    settle: float = 0.5
    timeout: float = 1.0
    std_limits: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    drift_limits: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))
    noise_floor: Mapping[str, float] = dataclasses.field(default_factory=lambda: MappingProxyType({}))


#: default tolerances of the envelope's live watch (channel units: m, rad)
ENVELOPE_TOLERANCE = {"distance": 0.05, "tilt": 0.0873, "roll": 0.0873, "pitch": 0.0873,
                      "yaw": 0.0873, "marker": 0.05}   # marker: each coordinate of a point


@dataclass(frozen=True)
class EnvelopeConfig:
    """The session's safety envelope (:mod:`station.planning.envelope`).

    qm_min, qm_max: per actuator, the range the station may command (actuator units;
                    None: the config sets no limit on that side). For the wrist: the
                    sliders' stroke.
    tolerance:      channel -> largest ``|live reading - model prediction|`` tolerated
                    while moving (channel units: m, rad); channels not listed are not
                    watched. Default :data:`ENVELOPE_TOLERANCE`.
    poll:           s between live readings while moving.
    latency:        s a sensor's reading may lag the actuators' (frame period, bus,
                    filter): a reading is compared with the predictions along the
                    path travelled over that time.
    """

    qm_min: tuple[float, ...] | None = None
    qm_max: tuple[float, ...] | None = None
    tolerance: Mapping[str, float] = dataclasses.field(
        default_factory=lambda: MappingProxyType(dict(ENVELOPE_TOLERANCE)))
    poll: float = 0.05
    latency: float = 0.15

    @property
    def qm_range(self) -> np.ndarray | None:
        """``(n, 2)`` of ``(min, max)`` per actuator (-inf/inf on an open side), or None
        when neither side is set."""
        if self.qm_min is None and self.qm_max is None:
            return None
        n = len(self.qm_min if self.qm_min is not None else self.qm_max)
        lo = np.full(n, -np.inf) if self.qm_min is None else np.asarray(self.qm_min, float)
        hi = np.full(n, np.inf) if self.qm_max is None else np.asarray(self.qm_max, float)
        return np.column_stack([lo, hi])


@dataclass(frozen=True)
class SessionConfig:
    """``[session]``: how a headless session rides out a device's trouble.

    retry_window: seconds a failing pose (or the reference step) is retried, after the
                  growing pauses of :func:`station.session.device_loss.backoff`, before the
                  session asks whether its device is gone (then it stops, naming it).
                  0 (default): three retries, after 0.25, 0.5 and 1 s. A node that
                  answers late for a while (a busy bus, a drive's firmware) is ridden
                  out with a window longer than the while.
    """

    retry_window: float = 0.0


#: the longest retry window a station config may set (s)
MAX_RETRY_WINDOW_S = 3600.0


def _snapshot(r: KeyReader) -> SnapshotConfig:
    cfg = SnapshotConfig(
        samples=r.int("samples", default=10, lo=1, hi=10000),
        period=r.float("period", default=0.02, lo=0.0, hi=MAX_PERIOD_S),
        settle=r.float("settle", default=0.5, lo=0.0, hi=MAX_TIMEOUT_S),
        timeout=r.float("timeout", default=1.0, lo=0.0, lo_open=True, hi=MAX_TIMEOUT_S),
        std_limits=_limits(r, "std_limits"), drift_limits=_limits(r, "drift_limits"),
        noise_floor=_limits(r, "noise_floor"))
    r.finish()
    return cfg

def _limits(r: KeyReader, key: str) -> Mapping[str, float]:
    t = r.table(key, required=False)
    if t is None:
        return frozen_map({})
    out = {}
    for ch in t.keys():
        if not LIMIT_CHANNEL.match(ch):
            t.fail(ch, "unknown channel (known: qm, qmN, tilt, roll, pitch, yaw, distance)")
        out[ch] = t.float(ch, lo=0.0)
    t.finish()
    return frozen_map(out)

def _envelope(r: KeyReader, n: int) -> EnvelopeConfig:
    lo = r.float_list("qm_min", length=n, default=None)
    hi = r.float_list("qm_max", length=n, default=None)
    if lo is not None and hi is not None and any(a >= b for a, b in zip(lo, hi)):
        r.fail("qm_max", "every qm_max must be above its qm_min")
    tol = dict(ENVELOPE_TOLERANCE)
    t = r.table("tolerance", required=False)
    if t is not None:
        for ch in t.keys():
            if ch not in ENVELOPE_TOLERANCE:
                t.fail(ch, f"unknown channel (known: {', '.join(ENVELOPE_TOLERANCE)})")
            tol[ch] = t.float(ch, lo=0.0, lo_open=True)
        t.finish()
    cfg = EnvelopeConfig(qm_min=lo, qm_max=hi, tolerance=frozen_map(tol),
                         poll=r.float("poll", default=0.05, lo=0.0, lo_open=True, hi=MAX_PERIOD_S),
                         latency=r.float("latency", default=0.15, lo=0.0, hi=MAX_PERIOD_S))
    r.finish()
    return cfg

def _session(r: KeyReader) -> SessionConfig:
    cfg = SessionConfig(retry_window=r.float("retry_window", default=0.0, lo=0.0,
                                             hi=MAX_RETRY_WINDOW_S))
    r.finish()
    return cfg

def _display(r: KeyReader) -> DisplayConfig:
    cfg = DisplayConfig(length=r.choice("length", DISPLAY_LENGTHS, default="mm"),
                        angle=r.choice("angle", DISPLAY_ANGLES, default="deg"))
    r.finish()
    return cfg
