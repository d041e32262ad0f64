"""Snapshot statistics and the faults it must catch (small in-test devices)."""
from __future__ import annotations

import dataclasses
import math
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from drivers.base import Device, Sample
from drivers.config import load_station_config
from drivers.errors import DeviceError, DeviceTimeout
from drivers.snapshot import (FrozenReading, Snapshot, StaleReading, UnstableReading, limit_for,
                              snapshot_with, take_snapshot)


class Scripted(Device):
    """Gives ``values(i)`` at read i, taken at ``t0 + i * dt``, with ``seq(i)``."""

    def __init__(self, name, values, *, dt=0.1, seq=lambda i: i + 1, fail_at=None):
        super().__init__(name)
        self.values, self.dt, self.seq, self.fail_at = values, dt, seq, fail_at
        self.i = 0
        self.timeouts = []

    def _open_internal(self):
        pass

    def _close_internal(self):
        pass

    def _read_internal(self, timeout):
        self.timeouts.append(timeout)
        if self.fail_at is not None and self.i == self.fail_at:
            raise DeviceTimeout("no answer", device=self.name)
        i, self.i = self.i, self.i + 1
        return Sample(t=100.0 + i * self.dt, values=self.values(i), seq=self.seq(i))


class Clock:
    """Fake monotonic clock: sleep() advances it and records the waits."""

    def __init__(self):
        self.t, self.sleeps = 0.0, []

    def __call__(self):
        return self.t

    def sleep(self, s):
        self.sleeps.append(s)
        self.t += s


def snap(devices, **kw):
    clock = Clock()
    for d in devices:
        d.open()
    kw.setdefault("samples", 5)
    kw.setdefault("period", 0.1)
    return take_snapshot(devices, sleep=clock.sleep, clock=clock, **kw), clock


NOISE = [0.3, -1.1, 0.8, -0.2, 0.5, -0.9, 1.2, -0.6]


def test_mean_std_drift_and_timing():
    enc = Scripted("drives", lambda i: {"qm1": 10.0 + 0.5 * i, "qm2": -3.0})
    inc = Scripted("inclinometer", lambda i: {"tilt": 0.1 + 1e-4 * NOISE[i]})
    s, clock = snap([enc, inc], settle=0.7, timeout=0.25)
    assert isinstance(s, Snapshot) and s.samples == 5
    assert clock.sleeps[0] == 0.7 and clock.sleeps[1:] == pytest.approx([0.1] * 4)
    assert s.mean["qm1"] == pytest.approx(11.0) and s.mean["qm2"] == -3.0
    assert s.std["qm1"] == pytest.approx(np.std([10, 10.5, 11, 11.5, 12], ddof=1))
    assert s.std["qm2"] == 0.0 and s.drift["qm2"] == 0.0
    assert s.drift["qm1"] == pytest.approx(2.0)  # slope 5 /s over 0.4 s
    v = 0.1 + 1e-4 * np.array(NOISE[:5])
    assert s.mean["tilt"] == pytest.approx(v.mean()) and s.std["tilt"] == pytest.approx(v.std(ddof=1))
    slope = np.polyfit(np.arange(5) * 0.1, v, 1)[0]
    assert s.drift["tilt"] == pytest.approx(slope * 0.4)
    assert s.devices == {"qm1": "drives", "qm2": "drives", "tilt": "inclinometer"}
    assert s.duration == pytest.approx(0.4)
    assert datetime.fromisoformat(s.t_start) <= datetime.fromisoformat(s.t_end)
    assert enc.timeouts == [0.25] * 5
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.samples = 3


def test_one_sample_and_equal_times():
    d = Scripted("d", lambda i: {"distance": 1.0 + i}, dt=0.0)
    s, _ = snap([d], samples=1)
    assert s.std == {"distance": 0.0} and s.drift == {"distance": 0.0}
    s, _ = snap([Scripted("d", lambda i: {"distance": 1.0 + i}, dt=0.0)], samples=3)
    assert s.drift["distance"] == pytest.approx(2.0)  # by index where times are equal


def test_std_limit_exceeded_names_channel_value_and_limit():
    inc = Scripted("inclinometer", lambda i: {"tilt": 0.01 * NOISE[i]})
    with pytest.raises(UnstableReading) as e:
        snap([inc], std_limits={"tilt": 1e-3})
    err = e.value
    assert isinstance(err, DeviceError)
    assert (err.device, err.channel, err.kind, err.limit) == ("inclinometer", "tilt", "std", 1e-3)
    assert err.value == pytest.approx(np.std(0.01 * np.array(NOISE[:5]), ddof=1))
    assert str(err).startswith("inclinometer: unstable reading: inclinometer channel 'tilt': std")
    assert "exceeds the limit 0.001" in str(err)


def test_drift_limit_and_all_violations_listed():
    drives = Scripted("drives", lambda i: {"qm1": 5.0 + 0.01 * i, "qm2": 1.0 + 0.01 * i})
    wire = Scripted("drawwire", lambda i: {"distance": 0.5 + 1e-3 * i})
    with pytest.raises(UnstableReading) as e:
        snap([drives, wire], std_limits={"qm": 1.0, "distance": 1.0},
             drift_limits={"qm": 0.02, "qm2": 0.1, "distance": 1e-3})
    found = {(v.channel, v.kind) for v in e.value.violations}
    assert found == {("qm1", "drift"), ("distance", "drift")}  # qm2 has its own, larger limit
    assert e.value.violations[0].value == pytest.approx(0.04)
    # inside the limits: a reading
    s, _ = snap([Scripted("drives", lambda i: {"qm1": 5.0 + 0.001 * i})], drift_limits={"qm": 0.02})
    assert s.drift["qm1"] == pytest.approx(0.004)


def test_limit_lookup():
    assert limit_for({"qm": 1.0, "qm3": 2.0}, "qm3") == 2.0
    assert limit_for({"qm": 1.0}, "qm12") == 1.0
    assert limit_for({"qm": 1.0}, "tilt") is None and limit_for(None, "qm1") is None
    assert limit_for({"qm": 1.0}, "qmx") is None


def test_stale_sequence_is_a_device_error():
    stuck = Scripted("inclinometer", lambda i: {"roll": 0.01 * NOISE[i]},
                     seq=lambda i: 7 if i >= 2 else 5 + i)
    with pytest.raises(StaleReading, match=r"^inclinometer: stale reading of roll: sample 4 repeats seq 7"):
        snap([stuck])
    assert issubclass(StaleReading, DeviceError)
    backwards = Scripted("drives", lambda i: {"qm1": 1.0}, seq=lambda i: 10 - i)
    with pytest.raises(StaleReading):
        snap([backwards])


def test_unnumbered_or_non_promising_devices_are_exempt():
    s, _ = snap([Scripted("plain", lambda i: {"qm1": 1.0}, seq=lambda i: 0)])
    assert s.mean["qm1"] == 1.0
    lazy = Scripted("lazy", lambda i: {"qm1": 1.0}, seq=lambda i: 3)
    lazy.promises_fresh = False
    assert snap([lazy])[0].samples == 5


def test_frozen_channel_with_a_noise_floor():
    frozen = Scripted("inclinometer", lambda i: {"tilt": 0.123456, "roll": 0.01 * NOISE[i]})
    with pytest.raises(FrozenReading) as e:
        snap([frozen], noise_floor={"tilt": 1e-4, "roll": 1e-4})
    assert isinstance(e.value, DeviceError)
    assert (e.value.device, e.value.channel, e.value.value) == ("inclinometer", "tilt", 0.123456)
    assert "5 bit-identical readings 0.123456" in str(e.value)
    # no noise floor (an encoder at standstill): identical values are a reading
    s, _ = snap([Scripted("inclinometer", lambda i: {"tilt": 0.123456})], noise_floor={"roll": 1e-4})
    assert s.std["tilt"] == 0.0
    # too few samples to tell
    s, _ = snap([Scripted("i", lambda i: {"tilt": 0.5})], samples=2, noise_floor={"tilt": 1e-4})
    assert s.mean["tilt"] == 0.5
    # a value that moves by one quantum is not frozen
    s, _ = snap([Scripted("i", lambda i: {"tilt": 0.5 + (i == 4) * 1e-9})], noise_floor={"tilt": 1e-4})
    assert s.samples == 5


def test_device_faults_propagate_and_channels_are_checked():
    with pytest.raises(DeviceTimeout, match="^drawwire: no answer"):
        snap([Scripted("drawwire", lambda i: {"distance": 1.0}, fail_at=2)])
    a = Scripted("a", lambda i: {"qm1": 1.0})
    b = Scripted("b", lambda i: {"qm1": 2.0})
    with pytest.raises(DeviceError, match=r"^b: channel 'qm1' is also given by a"):
        snap([a, b])
    c = Scripted("c", lambda i: {"qm1": 1.0} if i < 3 else {"qm2": 1.0})
    with pytest.raises(DeviceError, match=r"^c: sample 4 has channels \['qm2'\]"):
        snap([c])
    closed = Scripted("closed", lambda i: {"qm1": 1.0})
    with pytest.raises(DeviceError, match="not open"):
        take_snapshot([closed], samples=1, period=0.0)
    with pytest.raises(DeviceError, match="non-finite"):
        snap([Scripted("nan", lambda i: {"tilt": math.nan})])
    with pytest.raises(ValueError, match="samples"):
        take_snapshot([a], samples=0)


def test_with_station_config_and_real_time():
    cfg = load_station_config(Path(__file__).resolve().parents[2] / "fixtures" / "stations"
                              / "sim-sm.toml").snapshot
    dev = Scripted("inclinometer", lambda i: {"tilt": 0.2 + 1e-4 * NOISE[i % 8]})
    dev.open()
    s = snapshot_with([dev], cfg, settle=0.0, period=0.005)
    assert s.samples == cfg.samples
    assert s.duration == pytest.approx((cfg.samples - 1) * 0.005, abs=0.05)
    noisy = Scripted("inclinometer", lambda i: {"tilt": 0.01 * NOISE[i % 8]}).open()
    with pytest.raises(UnstableReading, match="tilt"):
        snapshot_with([noisy], cfg, settle=0.0, period=0.0)
