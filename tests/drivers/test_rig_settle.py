"""A snapshot taken while a sensor still settles is measured again, not a fault: the
simulated inclinometer lags the arm (its frames show the pose of ``inclinometer_lag_s``
before), so right after a fast move its readings still drift; the rig waits and takes
the snapshot again. Readings that never settle are the device's fault."""
from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.base import Device, Sample
from drivers.config import SnapshotConfig
from drivers.rig import SETTLE_RETAKES, Rig, retake_waits
from drivers.sim.server import SimulatorProcess
from drivers.snapshot import UnstableReading
from station.simulation.sessions import fast_config

ROOT = Path(__file__).resolve().parents[2]
UNSEEN = ROOT / "fixtures" / "truth" / "agebot-sm-unseen.json"


def test_retake_waits_double_from_the_settle():
    assert retake_waits(0.01) == pytest.approx([0.1, 0.2, 0.4])
    assert retake_waits(0.5) == pytest.approx([0.5, 1.0, 2.0])
    assert len(retake_waits(0.0)) == SETTLE_RETAKES


@pytest.fixture(scope="module")
def sim_rig(tmp_path_factory):
    """The unseen arm at the fixture's own speed (a long move: 0.7 s)."""
    cfg = fast_config("agebot-sm", tmp_path_factory.mktemp("settle"), speed=1.0)
    with SimulatorProcess("agebot-sm", truth=str(UNSEEN), config=str(cfg), seed=23) as sim:
        with Rig(sim.station_config()) as rig:
            yield sim, rig


def test_a_late_sensor_is_measured_again_once_it_settled(sim_rig):
    """A 0.7 s move with the inclinometer 0.5 s late, the snapshot at once (the
    config's settle, 50 ms; still inside the move should this process run up to 0.4 s
    late): still moving, told, measured again; what it keeps is the pose at rest (a
    snapshot a second later, the lag gone, agrees)."""
    sim, rig = sim_rig
    start = np.array(rig.qm())
    told = []
    with sim.control() as ctl:
        ctl.call(faults={"inclinometer_lag_s": 0.5})
    try:
        t0 = time.monotonic()
        rig.move_to(start + np.array([20.0, 120.0, -100.0, 80.0]))
        moved = time.monotonic() - t0
        snap = rig.snapshot(on_retake=lambda e, wait: told.append((e, wait)))
        with sim.control() as ctl:
            ctl.call(faults={"inclinometer_lag_s": 0.0})
        time.sleep(1.0)
        later = rig.snapshot()
    finally:
        with sim.control() as ctl:
            ctl.call(faults={"inclinometer_lag_s": 0.0})
        rig.move_to(start)
    assert moved > 0.6           # the premise: the lagged frames show the arm moving
    assert told and all(isinstance(e, UnstableReading) and e.channel == "tilt"
                        for e, _ in told)
    assert [w for _, w in told] == retake_waits(rig.config.snapshot.settle)[:len(told)]
    assert abs(snap.mean["tilt"] - later.mean["tilt"]) < 5 * max(later.std["tilt"], 1e-4)
    assert abs(snap.mean["distance"] - later.mean["distance"]) < 1e-3


class Drifting(Device):
    """A sensor that never settles (a robot that keeps vibrating): its tilt climbs."""

    def __init__(self):
        super().__init__("inclinometer")
        self.i = 0

    def _open_internal(self):
        pass

    def _close_internal(self):
        pass

    def _read_internal(self, timeout):
        self.i += 1
        return Sample(t=float(self.i), values={"tilt": 0.01 * self.i}, seq=self.i)


def test_readings_that_never_settle_are_the_devices_fault(monkeypatch):
    """Still unstable after every wait: the UnstableReading goes to the session's fault
    policy (the operator is asked), after :data:`SETTLE_RETAKES` retakes."""
    rig = Rig.__new__(Rig)
    rig.config = SimpleNamespace(snapshot=SnapshotConfig(
        samples=5, period=0.0, settle=0.0, drift_limits={"tilt": 0.001}))
    rig.actuators, rig.inclinometer, rig.drawwire = Drifting(), None, None
    rig.actuators.open()
    slept, told = [], []
    monkeypatch.setattr("drivers.rig.time", SimpleNamespace(sleep=slept.append,
                                                            monotonic=time.monotonic))
    with pytest.raises(UnstableReading) as e:
        rig.snapshot(on_retake=lambda err, wait: told.append(wait))
    assert e.value.channel == "tilt" and e.value.kind == "drift"
    assert told == slept == retake_waits(0.0) and len(told) == SETTLE_RETAKES
    assert rig.actuators.i == 5 * (SETTLE_RETAKES + 1)     # four whole snapshots
