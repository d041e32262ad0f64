"""A device gone for good stops the session at once, naming it and what to check;
the trace stays resumable and the resumed session measures what is left once the
fault is cleared. Short outages are retried after a pause. Faults are injected
through the simulator's control port (drivers/sim/server.py), on the wire."""
from __future__ import annotations

import os
import signal
import threading

import pytest

from drivers.sim.server import SimulatorProcess
from station.device_loss import DeviceLost
from station.planner import PlanRequest
from station.session import Session
from station.trace import read_trace
from tests.station.test_session import _session_config, fast_config

REQUEST = PlanRequest(count=8, validation=2, seed=3)
# 8 poses identify only part of the arm, and the quality gate rightly refuses the fit;
# these tests are about losing a device, so the resumed sessions keep it anyway
POOR_FIT_OK = {"accept_poor_fit": True}


def _inject_after(ctl, n: int, faults: dict, done: list):
    """An observer that injects ``faults`` once ``n`` poses are recorded."""
    def observer(kind, payload):
        if kind == "progress" and payload.readings and payload.done == n and not done:
            done.append(ctl.call(faults=faults))
    return observer


@pytest.mark.parametrize("faults, device, check", [
    ({"silent_nodes": [2]}, "canopen", "check the CAN cable"),
    ({"modbus_exception": 4}, "draw-wire", "check the Modbus link"),
    ({"inclinometer_silent": True}, "inclinometer", "check the serial cable"),
])
def test_a_lost_device_stops_the_session_and_the_resume_finishes_it(
        tmp_path, faults, device, check, quick_retries, no_report):
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        with sim.control() as ctl:
            injected = []
            with Session(config, "sm-distance-tilt", out, request=REQUEST,
                         observer=_inject_after(ctl, 3, faults, injected)) as s:
                with pytest.raises(DeviceLost) as lost:
                    s.run()
            assert injected
            msg = str(lost.value)
            print(msg)
            assert "\n" not in msg and msg.startswith(device) and check in msg, msg
            assert "run the session again" in msg
            trace = read_trace(out / "trace.jsonl")
            assert len(trace.poses) == 3, "the session went on measuring without the device"
            assert not [e for e in trace.events if e["kind"] == "skip"], \
                "poses were skipped instead of stopping"
            assert [e for e in trace.events if e["kind"] == "lost"]
            ctl.call(clear=True)                         # the fault is cleared
        with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK) as again:
            assert len(again.pending) == 10 - 3
            again.run()
    trace = read_trace(out / "trace.jsonl")
    idx = sorted(p["plan_index"] for p in trace.poses)
    assert idx == list(range(10)) and again.outcome.result.converged


def test_a_killed_simulator_stops_the_session_and_a_new_one_resumes_it(tmp_path, quick_retries,
                                                                      no_report):
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        killed = []

        def observer(kind, payload):
            if kind == "progress" and payload.readings and payload.done == 2 and not killed:
                os.kill(sim.proc.pid, signal.SIGKILL)
                killed.append(sim.proc.wait())

        with Session(_session_config(sim, cfg), "sm-distance-tilt", out, request=REQUEST,
                     observer=observer) as s:
            with pytest.raises(DeviceLost, match=r"does not answer .*: check .*run the "
                                                 r"session again") as lost:
                s.run()
            print(lost.value)
    assert killed and len(read_trace(out / "trace.jsonl").poses) == 2
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        with Session(_session_config(sim, cfg), "sm-distance-tilt", out, request=REQUEST,
                     **POOR_FIT_OK) as s:
            s.run()
    trace = read_trace(out / "trace.jsonl")
    assert sorted(p["plan_index"] for p in trace.poses) == list(range(10))
    assert s.outcome.result.converged


def test_a_short_outage_is_retried_after_a_pause(tmp_path):
    """The draw-wire's Modbus server down for 1 s: retries after 0.25, 0.5, 1 s get
    the pose; nothing is skipped."""
    cfg = fast_config(tmp_path, "agebot-sm")
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        with sim.control() as ctl:
            def observer(kind, payload):
                if kind == "progress" and payload.readings and payload.done == 2:
                    ctl.call(faults={"drawwire_down": True})
                    threading.Timer(1.0, lambda: ctl.call(faults={"drawwire_down": False})
                                    ).start()

            with Session(_session_config(sim, cfg), "sm-distance-tilt", tmp_path / "run",
                         request=REQUEST, observer=observer) as s:
                s.connect()
                s.move_to(s.reference_target()[0])
                s.capture_reference()
                s.plan()
                s.execute()
    kinds = [e["kind"] for e in s.events]
    assert "retry" in kinds and "skip" not in kinds and "lost" not in kinds
    assert len(s.measured) == 10
