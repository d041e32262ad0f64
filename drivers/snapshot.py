"""One measurement of a pose: N samples of every channel of every device, checked.

:func:`take_snapshot` waits for the motion to settle, reads every device ``samples``
times ``period`` seconds apart and returns a frozen :class:`Snapshot` with the
mean, sample standard deviation and drift of each channel. A reading the
station cannot trust is an error, never a value:

* :class:`StaleReading` -- a device repeats a sample: ``Sample.seq`` does not
  increase from one read to the next although ``Device.read`` promises a fresh
  datum (a device without sequence numbers, every ``seq == 0``, or one whose
  ``promises_fresh`` attribute is False, is exempt);
* :class:`FrozenReading` -- a channel whose configured noise floor says it must
  move gives bit-identical values over the whole snapshot (at least
  ``FROZEN_MIN_SAMPLES`` samples);
* :class:`UnstableReading` -- a channel's std or |drift| exceeds its limit
  (the robot still moves, vibrates, or a sensor drifts).

Limits (``std_limits``, ``drift_limits``, ``noise_floor``) map channel -> value in
the channel's unit (m, rad, actuator units); the key ``qm`` covers every ``qmN``
that has no key of its own; a channel without a limit is not checked.
Drift is the least-squares slope of the values over their reception times times
the snapshot's duration (robust to noise, unlike last - first).
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Callable, Mapping, Sequence

import numpy as np

from drivers.base import Device, Sample
from drivers.errors import DeviceError

FROZEN_MIN_SAMPLES = 3
_QM = re.compile(r"^qm[0-9]+$")


class StaleReading(DeviceError):
    """A device returned the same datum twice (``Sample.seq`` did not advance)."""


class FrozenReading(DeviceError):
    """A channel that must show noise gave bit-identical values: the sensor is frozen."""

    def __init__(self, message: str, *, device: str | None = None, channel: str = "",
                 value: float = 0.0, noise_floor: float = 0.0):
        self.channel, self.value, self.noise_floor = channel, value, noise_floor
        super().__init__(message, device=device)


@dataclass(frozen=True)
class Violation:
    """One stability limit exceeded: ``kind`` is ``"std"`` or ``"drift"``."""

    device: str
    channel: str
    kind: str
    value: float
    limit: float

    def __str__(self) -> str:
        return (f"{self.device} channel {self.channel!r}: {self.kind} {self.value:.3g} "
                f"exceeds the limit {self.limit:.3g}")


class UnstableReading(DeviceError):
    """One or more channels were not stable enough; ``violations`` lists them all,
    ``channel``/``kind``/``value``/``limit`` are those of the first."""

    def __init__(self, violations: Sequence[Violation]):
        self.violations = tuple(violations)
        first = self.violations[0]
        self.channel, self.kind, self.value, self.limit = (
            first.channel, first.kind, first.value, first.limit)
        super().__init__("unstable reading: " + "; ".join(map(str, self.violations)),
                         device=first.device)


@dataclass(frozen=True)
class Snapshot:
    """A checked measurement of one pose.

    mean, std, drift: channel -> value (channel units); std is the sample std (ddof 1,
                      0 for one sample), drift the fitted change over the snapshot.
    samples:          readings per channel.
    t_start, t_end:   ISO 8601 UTC of the first read and after the last.
    duration:         seconds from the first to the last read (monotonic clock).
    devices:          channel -> name of the device that gave it.
    """

    mean: dict[str, float]
    std: dict[str, float]
    drift: dict[str, float]
    samples: int
    t_start: str
    t_end: str
    duration: float = 0.0
    devices: dict[str, str] | None = None


def limit_for(limits: Mapping[str, float] | None, channel: str) -> float | None:
    """The limit of ``channel`` in ``limits`` (``qm`` covers ``qmN``), or None."""
    if not limits:
        return None
    if channel in limits:
        return float(limits[channel])
    if _QM.match(channel) and "qm" in limits:
        return float(limits["qm"])
    return None


def _utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def _drift(t: np.ndarray, v: np.ndarray) -> float:
    """Least-squares slope of ``v`` over ``x`` times the span of ``x``; ``x`` is ``t``,
    or the sample index where all times are equal."""
    if len(v) < 2:
        return 0.0
    x = t - t[0] if np.ptp(t) > 0 else np.arange(len(v), dtype=float)
    xc = x - x.mean()
    slope = float(np.dot(xc, v - v.mean()) / np.dot(xc, xc))
    return slope * float(x[-1] - x[0])


def take_snapshot(devices: Sequence[Device], *, samples: int = 10, period: float = 0.02,
                  settle: float = 0.0, std_limits: Mapping[str, float] | None = None,
                  drift_limits: Mapping[str, float] | None = None,
                  noise_floor: Mapping[str, float] | None = None, timeout: float = 1.0,
                  sleep: Callable[[float], None] = time.sleep,
                  clock: Callable[[], float] = time.monotonic) -> Snapshot:
    """Measure one pose with every device in ``devices`` (open).

    samples: readings per channel (>= 1); period: s between reads of one device;
    settle: s to wait first; timeout: s a single ``Device.read`` may take.
    Raises DeviceTimeout/DeviceError from the devices, and StaleReading,
    FrozenReading, UnstableReading (module docstring).
    """
    if samples < 1:
        raise ValueError(f"samples must be >= 1, not {samples!r}")
    if period < 0 or settle < 0:
        raise ValueError("period and settle must be >= 0 seconds")
    if settle > 0:
        sleep(settle)
    for d in devices:      # a streaming device's frames from before the settle are not of the pose
        discard = getattr(d, "discard_pending", None)
        if discard is not None:
            discard()
    reads: dict[str, list[Sample]] = {d.name: [] for d in devices}
    t_start, t0 = _utc_now(), clock()
    for i in range(samples):
        wait = t0 + i * period - clock()
        if wait > 0:
            sleep(wait)
        for d in devices:
            reads[d.name].append(d.read(timeout))
    duration, t_end = clock() - t0, _utc_now()

    owner: dict[str, str] = {}
    series: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for d in devices:
        got = reads[d.name]
        _check_fresh(d, got)
        channels = list(got[0].values)
        for k, s in enumerate(got[1:], start=2):
            if set(s.values) != set(channels):
                raise DeviceError(f"sample {k} has channels {sorted(s.values)}, the first "
                                  f"had {sorted(channels)}", device=d.name)
        for ch in channels:
            if ch in owner:
                raise DeviceError(f"channel {ch!r} is also given by {owner[ch]}", device=d.name)
            owner[ch] = d.name
            series[ch] = (np.array([s.t for s in got], dtype=float),
                          np.array([s.values[ch] for s in got], dtype=float))

    mean, std, drift, bad = {}, {}, {}, []
    for ch, (t, v) in series.items():
        floor = limit_for(noise_floor, ch)
        if floor and len(v) >= FROZEN_MIN_SAMPLES and np.all(v == v[0]):
            raise FrozenReading(
                f"channel {ch!r} is frozen: {len(v)} bit-identical readings {float(v[0])!r}, "
                f"but its noise floor is {floor:.3g}", device=owner[ch], channel=ch,
                value=float(v[0]), noise_floor=floor)
        dv = v - v[0]  # exact 0 for a constant channel, fewer rounding errors otherwise
        mean[ch] = float(v[0] + dv.mean())
        std[ch] = float(dv.std(ddof=1)) if len(v) > 1 else 0.0
        drift[ch] = _drift(t, v)
        for kind, value, limits in (("std", std[ch], std_limits),
                                    ("drift", abs(drift[ch]), drift_limits)):
            lim = limit_for(limits, ch)
            if lim is not None and value > lim:
                bad.append(Violation(owner[ch], ch, kind, value, lim))
    if bad:
        raise UnstableReading(bad)
    return Snapshot(mean=mean, std=std, drift=drift, samples=samples, t_start=t_start,
                    t_end=t_end, duration=duration, devices=owner)


def _check_fresh(device: Device, got: list[Sample]) -> None:
    """StaleReading where a device that numbers its samples repeats one."""
    if not getattr(device, "promises_fresh", True):
        return
    seqs = [s.seq for s in got]
    if not any(seqs):
        return
    for k in range(1, len(seqs)):
        if seqs[k] <= seqs[k - 1]:
            raise StaleReading(
                f"stale reading of {', '.join(got[k].values) or 'its channels'}: sample "
                f"{k + 1} repeats seq {seqs[k]} (previous {seqs[k - 1]}); the device "
                "stopped delivering fresh data", device=device.name)


def snapshot_with(devices: Sequence[Device], config, **overrides) -> Snapshot:
    """:func:`take_snapshot` with the settings of a :class:`drivers.config.SnapshotConfig`."""
    kw = dict(samples=config.samples, period=config.period, settle=config.settle,
              timeout=config.timeout, std_limits=config.std_limits,
              drift_limits=config.drift_limits, noise_floor=config.noise_floor)
    kw.update(overrides)
    return take_snapshot(devices, **kw)
