"""A device gone for good stops the session at once, naming it and what to check;
the trace stays resumable and the resumed session measures what is left once the
fault is cleared. Short outages are retried after a pause. Faults are injected
through the simulator's control port (drivers/sim/server.py), on the wire."""
from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest

from drivers.sim.server import SimulatorProcess
from station.session.device_loss import DeviceLost
from station.planning.request import PlanRequest
from station.session.session import Session
from station.recording.trace import read_trace
from tests.station.test_session import _session_config, fast_config

REQUEST = PlanRequest(count=8, validation=2, seed=3)
# 8 poses identify only part of the arm, and the quality gate rightly refuses the fit;
# these tests are about losing a device, so the resumed sessions keep it anyway
POOR_FIT_OK = {"accept_poor_fit": True}


#: a device that stops answering: the fault, the device named, what the operator checks
LOST_DEVICES = [
    ({"silent_nodes": [2]}, "canopen", "check the CAN cable"),
    ({"modbus_exception": 4}, "draw-wire", "check the Modbus link"),
    ({"inclinometer_silent": True}, "inclinometer", "check the serial cable"),
]


def _stopped_lost(config, out, observer, device: str, check: str):
    """Run a session that must stop with :class:`DeviceLost`: its one-line message names
    ``device`` and says ``check``, and the trace has a ``lost`` event. ``(message,
    trace)``."""
    with Session(config, "sm-distance-tilt", out, request=REQUEST, observer=observer) as s:
        with pytest.raises(DeviceLost) as lost:
            s.run()
    msg = str(lost.value)
    print(msg)
    assert "\n" not in msg and msg.startswith(device) and check in msg, msg
    trace = read_trace(out / "trace.jsonl")
    assert [e for e in trace.events if e["kind"] == "lost"]
    return msg, trace


def _inject_after(ctl, n: int, faults: dict, done: list):
    """An observer that injects ``faults`` once ``n`` poses are recorded."""
    def observer(kind, payload):
        if kind == "progress" and payload.readings and payload.done == n and not done:
            done.append(ctl.call(faults=faults))
    return observer


@pytest.mark.parametrize("faults, device, check", LOST_DEVICES)
def test_a_lost_device_stops_the_session_and_the_resume_finishes_it(
        tmp_path, faults, device, check, quick_retries, no_report):
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        with sim.control() as ctl:
            injected = []
            msg, trace = _stopped_lost(config, out, _inject_after(ctl, 3, faults, injected),
                                       device, check)
            assert injected
            assert "run the session again" in msg
            assert len(trace.poses) == 3, "the session went on measuring without the device"
            assert not [e for e in trace.events if e["kind"] == "skip"], \
                "poses were skipped instead of stopping"
            ctl.call(clear=True)                         # the fault is cleared
        with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK) as again:
            assert len(again.pending) == 10 - 3
            again.run()
    trace = read_trace(out / "trace.jsonl")
    # every planned pose measured (a reading the gate flags measured again: its newest)
    idx = sorted(p["plan_index"] for p in trace.current_poses)
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
    assert sorted(p["plan_index"] for p in trace.current_poses) == list(range(10))
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


def _at_reference_step(ctl, faults: dict, done: list):
    """An observer that injects ``faults`` as the headless run starts its reference
    step (its ``moving to the ... for the reference step`` event)."""
    def observer(kind, payload):
        if (kind == "event" and payload["kind"] == "info" and not done
                and "for the reference step" in payload["message"]):
            done.append(ctl.call(faults=faults))
    return observer


def test_a_lost_answer_in_the_reference_tare_redoes_the_whole_capture(tmp_path, quick_retries,
                                                                     no_report):
    """One draw-wire answer lost in the middle of the reference's tare (a flaky cable):
    a ``fault`` event naming the draw-wire, a retry, and the whole capture again, the
    zero among it (no reading of before the fault is kept); the session completes."""
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        n = config.snapshot.samples
        # the draw-wire's requests of the reference step, in order: the plausibility
        # check's zero and its two snapshots (before and after the test move), a snapshot
        # per move of the joints' direction test, then the capture's zero and the tare
        # snapshot: the tare's third reading gets no answer
        from calibration.robots import get_robot
        from station.session.joint_directions import direction_moves
        from station.planning.arm_plan import reference_pose

        robot = get_robot("agebot-sm")
        target = reference_pose("sm-distance-tilt", robot.nominal,
                                config.envelope.qm_range)[0]
        moves = 2 * len(direction_moves(robot, robot.nominal, target))
        first = 1 + 2 * n + moves * n + 1 + 2
        with sim.control() as ctl:
            injected = []
            with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK,
                         observer=_at_reference_step(
                             ctl, {"drawwire_answer_first": first, "drawwire_unanswered": 1},
                             injected)) as s:
                s.run()
            state = ctl.call(state=True)
    assert injected and state["faults"]["drawwire_unanswered"] == 0
    trace = read_trace(out / "trace.jsonl")
    faults = [e for e in trace.events if e["kind"] == "fault"]
    assert len(faults) == 1 and faults[0]["device"] == "draw-wire", faults
    assert faults[0]["step"] == "the reference step" and "no answer" in faults[0]["message"]
    assert [e["kind"] for e in trace.events].count("retry") == 1
    # two zeros an attempt (the plausibility check's, the capture's), both attempts
    assert state["drawwire_zero_calls"] == 4
    assert trace.reference["samples"] == n and trace.reference["tare"]["samples"] == n
    assert sorted(p["plan_index"] for p in trace.current_poses) == list(range(10))
    assert s.outcome.result.converged


def test_answers_lost_at_the_reference_step_s_first_requests_are_retried(tmp_path,
                                                                        quick_retries,
                                                                        no_report):
    """The plausibility check's zero of the draw-wire unanswered twice: two faults, two
    retries (each drives back to the base origin first), the third attempt records the
    reference; the trace resumes as any other (a second session finds it finished)."""
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        with sim.control() as ctl:
            injected = []
            with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK,
                         observer=_at_reference_step(ctl, {"drawwire_unanswered": 2},
                                                     injected)) as s:
                s.run()
            state = ctl.call(state=True)
        with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK) as again:
            assert again.finished
    trace = read_trace(out / "trace.jsonl")
    faults = [e for e in trace.events if e["kind"] == "fault"]
    assert [f["message"].split(":")[0] for f in faults] == [
        "the reference step, attempt 1", "the reference step, attempt 2"], faults
    assert all(f["device"] == "draw-wire" for f in faults)
    assert state["drawwire_zero_calls"] == 2           # the third attempt's two zeros
    assert len(trace.current_poses) == 10 and s.outcome.result.converged


# the reference step's own retry path is one for every device: the CAN node in the
# default suite, the serial and Modbus devices with the slow tests (the default suite
# stays under ten minutes)
@pytest.mark.parametrize("faults, device, check", [
    LOST_DEVICES[0], *(pytest.param(*d, marks=pytest.mark.slow) for d in LOST_DEVICES[1:])])
def test_a_device_lost_at_the_reference_step_stops_the_session_named(
        tmp_path, faults, device, check, quick_retries, no_report):
    """A device that stays silent from the reference step on: its retries fail, the
    probe finds it gone, the session stops naming it; once it answers again the
    session resumes from its trace (header and faults, no reference) and completes."""
    cfg = fast_config(tmp_path, "agebot-sm")
    out = tmp_path / "run"
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        with sim.control() as ctl:
            injected = []
            _, trace = _stopped_lost(config, out, _at_reference_step(ctl, faults, injected),
                                     device, check)
            assert injected
            assert trace.reference is None and not trace.poses
            tried = [e for e in trace.events if e["kind"] == "fault"
                     and e.get("step") == "the reference step"]
            assert len(tried) == 4, tried                  # the first try and 3 retries
            ctl.call(clear=True)
        with Session(config, "sm-distance-tilt", out, request=REQUEST, **POOR_FIT_OK) as again:
            assert again.resumed and again.redo().capture_reference
            again.run()
    trace = read_trace(out / "trace.jsonl")
    assert trace.reference is not None and len(trace.current_poses) == 10
    assert again.outcome.result.converged


def test_a_fault_at_the_wrist_s_start_step_is_retried(tmp_path, quick_retries):
    """The wrist's start step (its test move, the home pose's readings): the inclinometer
    silent until the fault is recorded, then answering again: one fault naming it, the
    step again from home, the scout round planned."""
    cfg = fast_config(tmp_path, "agebot-pm")
    with SimulatorProcess("agebot-pm", config=str(cfg), seed=4) as sim:
        with sim.control() as ctl:
            def observer(kind, payload):
                if kind == "event" and payload["kind"] == "fault":
                    ctl.call(faults={"inclinometer_silent": False})

            with Session(_session_config(sim, cfg), "pm-fk", tmp_path / "run",
                         request=PlanRequest(count=24, validation=5, seed=2),
                         observer=observer) as s:
                s.connect()
                home = s.qm()
                ctl.call(faults={"inclinometer_silent": True})
                poses = s.plan()
                assert np.allclose(s.qm(), home, atol=1e-3)   # back home after the test move
    faults = [e for e in s.events if e["kind"] == "fault"]
    assert len(faults) == 1 and faults[0]["device"] == "inclinometer", faults
    assert faults[0]["step"] == "the wrist's start step"
    assert poses and s.plan_poses == poses
    trace = read_trace(tmp_path / "run" / "trace.jsonl")
    assert [e["kind"] for e in trace.events][:3] == ["fault", "retry", "info"]


@pytest.mark.slow
def test_a_node_answering_late_for_a_while_is_ridden_out_within_the_retry_window(tmp_path):
    """Every CAN frame 1.5 s late for 8 s (the SDO timeout is 0.5 s): the default three
    retries would give the node up as lost; the station config's ``[session]
    retry_window = 30`` retries the pose until the node answers in time again, and
    the session measures every pose."""
    import dataclasses

    cfg = fast_config(tmp_path, "agebot-sm")
    with SimulatorProcess("agebot-sm", config=str(cfg), seed=9) as sim:
        config = _session_config(sim, cfg)
        config = dataclasses.replace(config, session=dataclasses.replace(config.session,
                                                                        retry_window=30.0))
        with sim.control() as ctl:
            done = []

            def observer(kind, payload):
                if kind == "progress" and payload.readings and payload.done == 2 and not done:
                    done.append(ctl.call(faults={"late_s": 1.5}))
                    threading.Timer(8.0, lambda: ctl.call(faults={"late_s": 0.0})).start()

            with Session(config, "sm-distance-tilt", tmp_path / "run", request=REQUEST,
                         observer=observer) as s:
                s.connect()
                s.move_to(s.reference_target()[0])
                s.capture_reference()
                s.plan()
                s.execute()
    kinds = [e["kind"] for e in s.events]
    assert done and "retry" in kinds and "lost" not in kinds and "skip" not in kinds
    assert len(s.measured) == 10
