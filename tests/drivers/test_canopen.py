"""CANopen drivers against the simulated nodes, over the wire.

The socketcand hub and the simulated drives run in a separate process
(``drivers.sim.cia402_drive.run_sim_process``); the drivers under test connect
through python-can's ``socketcand`` client. Faults are switched through the
simulator's control pipe. Correctness only, no timing assertions.
"""
from __future__ import annotations

import multiprocessing
import time

import can
import canopen
import pytest

from calibration.errors import ConfigError
from drivers.canopen_drives import CanopenActuators, CanopenEncoders, emcy_text
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.sim.cia402_drive import EDS_PATH, run_sim_process
from drivers.sim.socketcand_hub import SocketcandHub

RES = 10000.0                      # increments per actuator unit
NODES = [1, 2, 3, 4]
START = [0.0, 0.25, -0.5, 1.0]


class SimProcess:
    """The simulator process and its control pipe."""

    def __init__(self, **kwargs):
        ctx = multiprocessing.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=run_sim_process, args=(child,), kwargs=kwargs, daemon=True)
        self.proc.start()
        child.close()
        if not self.conn.poll(30):
            self.close()
            raise RuntimeError("simulator process did not start")
        status, self.endpoint = self.conn.recv()
        assert status == "ready"

    def call(self, *request):
        self.conn.send(request)
        if not self.conn.poll(30):
            raise RuntimeError(f"simulator did not answer {request!r}")
        status, result = self.conn.recv()
        if status != "ok":
            raise RuntimeError(result)
        return result

    def close(self):
        if self.proc.is_alive():
            try:
                self.call("stop")
            except (RuntimeError, OSError, EOFError):
                pass
            self.proc.join(10)
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(5)
        self.conn.close()


def eventually(fn, timeout=5.0):
    """Retry ``fn`` until it stops raising DeviceError (a recorded recovery)."""
    end = time.monotonic() + timeout
    while True:
        try:
            return fn()
        except DeviceError:
            if time.monotonic() > end:
                raise
            time.sleep(0.05)


@pytest.fixture(scope="module")
def sim():
    proc = SimProcess(nodes=NODES, positions=START, resolution=RES, velocity=4.0, acceleration=20.0)
    yield proc
    proc.close()
    assert not proc.proc.is_alive()


@pytest.fixture(autouse=True)
def _clean_faults(request):
    yield
    if "sim" in request.fixturenames:
        sim = request.getfixturevalue("sim")
        sim.call("clear")
        assert sim.call("drain")


@pytest.fixture
def drives(sim):
    drv = CanopenActuators.from_endpoint(sim.endpoint, RES, timeout=1.0)
    with drv:
        yield drv
    assert not drv.is_open


def test_enable_move_wait_read_cycle(drives, sim):
    drives.enable()
    targets = [0.5, -0.125, 0.75, 0.0]
    drives.move_to(targets)
    sample = drives.wait_target_reached(timeout=10)
    assert sample.values == {f"qm{i + 1}": pytest.approx(t, abs=1 / RES) for i, t in enumerate(targets)}
    assert all(sw & 0x0400 for sw in sample.info["statusword"].values())
    assert set(sample.info["state"].values()) == {"OPERATION ENABLED"}
    assert [sim.call("position", i) for i in range(4)] == pytest.approx(targets, abs=1e-9)
    drives.move_to(START)
    drives.wait_target_reached(timeout=10)


def test_a_block_of_slower_moves_writes_the_profile_and_back(sim):
    """``CanopenActuators.slower(f)``: inside, every drive's profile velocity is f times
    its own and its acceleration f**2 times (the same profile, stretched in time), read
    back over SDO; after, even after an error inside, the drive's own values again. A
    drive with no profile to slow down (0x6081 reads 0) is named."""
    vel, acc = [4.0, 2.0, 3.0, 1.0], [20.0, 10.0, 12.0, 8.0]
    with CanopenActuators.from_endpoint(sim.endpoint, RES, timeout=1.0) as plain:
        before = [(plain.sdo_read(n, 0x6081), plain.sdo_read(n, 0x6083)) for n in NODES]
    drv = CanopenActuators.from_endpoint(sim.endpoint, RES, timeout=1.0, velocity=vel,
                                         acceleration=acc)
    with drv:
        drv.enable()
        own = [(drv.sdo_read(n, 0x6081), drv.sdo_read(n, 0x6083)) for n in NODES]
        assert own == [(round(v * RES), round(a * RES)) for v, a in zip(vel, acc)]
        with pytest.raises(RuntimeError, match="inside"):
            with drv.slower(0.5):
                assert [(drv.sdo_read(n, 0x6081), drv.sdo_read(n, 0x6083)) for n in NODES] \
                    == [(round(v * RES / 2), round(a * RES / 4)) for v, a in zip(vel, acc)]
                drv.move_to([0.25, 0.0, -0.25, 0.5])
                drv.wait_target_reached(timeout=10)
                raise RuntimeError("inside")
        assert [(drv.sdo_read(n, 0x6081), drv.sdo_read(n, 0x6083)) for n in NODES] == own
        assert [sim.call("position", i) for i in range(4)] == pytest.approx(
            [0.25, 0.0, -0.25, 0.5], abs=1e-9)
        drv.move_to(START)
        drv.wait_target_reached(timeout=10)
        drv.sdo_write(NODES[1], 0x6081, 0)
        with pytest.raises(DeviceError, match="no profile to slow down") as e:
            with drv.slower(0.5):
                pass
        assert e.value.device == drv.node_name(NODES[1])
        with pytest.raises(ValueError):
            with drv.slower(1.5):
                pass
        for n, (v, a) in zip(NODES, before):     # the module's other tests: as they were
            drv.sdo_write(n, 0x6081, v)
            drv.sdo_write(n, 0x6083, a)


def test_move_after_a_master_died_mid_handshake(drives, sim):
    """A master killed between 'new set-point' (controlword bit 4 up) and taking it down
    leaves the acknowledge set; the next master's move must still start (a fresh rising
    edge), not return at once from the old target."""
    drives.enable()
    for nid in drives.nodes:                       # the dead master's half handshake
        drives.sdo_write(nid, 0x607A, round(0.25 * RES))
        drives.sdo_write(nid, 0x6040, 0x3F)
    eventually(lambda: drives._await(drives.nodes[0], lambda sw: sw & 0x1000, "ack", 2.0))
    targets = [-0.25, 0.125, 0.5, -0.5]
    drives.move_to(targets)
    drives.wait_target_reached(timeout=10)
    assert [sim.call("position", i) for i in range(4)] == pytest.approx(targets, abs=1e-9)
    drives.move_to(START)
    drives.wait_target_reached(timeout=10)


def test_tpdo_on_sync_matches_sdo_read(drives):
    a = drives.read()
    b = drives.read_sdo()
    c = drives.read()
    assert a.info["source"] == "tpdo" and b.info["source"] == "sdo"
    assert a.values == b.values == c.values
    assert a.info["increments"] == b.info["increments"]
    assert a.seq < b.seq < c.seq


def test_silent_node_is_heartbeat_lost_then_recovers(drives, sim):
    sim.call("faults", {"silent_nodes": [3]})
    with pytest.raises(DeviceTimeout, match="heartbeat lost") as err:
        drives.read()
    assert err.value.device == "canopen node 3"
    assert str(err.value).startswith("canopen node 3: ")
    sim.call("faults", {"silent_nodes": []})
    assert eventually(drives.read).values["qm3"] == pytest.approx(START[2])


def test_drive_fault_gives_emcy_then_reset_and_move(drives, sim):
    drives.enable()
    sim.call("faults", {"drive_fault_node": 2})
    with pytest.raises(ProtocolError) as err:
        drives.move_to([0.0, 0.5, -0.5, 1.0])
    assert err.value.device == "canopen node 2"
    assert err.value.code == 0x8611 and err.value.text == "following error"
    assert "0x8611" in str(err.value)
    assert sim.call("plan")["drive_fault_node"] == 0          # fired once
    assert drives.read().info["state"][2] == "FAULT"
    with pytest.raises(ProtocolError, match="following error"):
        drives.move_to(START)
    drives.fault_reset()
    drives.move_to([0.0, 0.5, -0.5, 1.0])
    assert drives.wait_target_reached(10).values["qm2"] == pytest.approx(0.5)
    drives.move_to(START)
    drives.wait_target_reached(10)


def test_dropped_tpdo_is_timeout_never_old_value(drives, sim):
    before = drives.read()
    sim.call("faults", {"drop_prob": 1.0})
    with pytest.raises(DeviceTimeout, match="stale sample refused") as err:
        drives.read(timeout=0.3)
    assert err.value.device == "canopen node 1"
    assert drives.read_sdo().values == before.values          # SDO fallback still answers
    sim.call("clear")
    after = drives.read()
    assert after.seq > before.seq and after.values == before.values


def _give_up_an_upload(drives, sim):
    """Every frame 1 s late from now (in order); node 1's upload of 0x1000 given up
    on after 0.05 s: its answer comes in 1 s after it was asked."""
    sim.call("faults", {"late_s": 1.0})
    drives.remote[1].sdo.RESPONSE_TIMEOUT = 0.05
    try:
        with pytest.raises(DeviceTimeout, match="0x1000"):
            drives.sdo_read(1, 0x1000)
    finally:
        drives.remote[1].sdo.RESPONSE_TIMEOUT = drives.timeout


def test_a_late_answer_to_a_request_given_up_on_is_not_taken_for_the_next(drives, sim):
    """An SDO request given up on (a timeout, or the TPDO barrier's time running out)
    can still be answered, after the next request was sent: that answer names another
    object and is dropped, and the next request gets its own answer (before, the
    SDO fallback after a dropped TPDO failed with "Node returned a value for 0x1000:00
    instead" on a loaded machine)."""
    expected = drives.read().values
    _give_up_an_upload(drives, sim)
    # asked at once: the answer above comes in first, this request's 0.05 s after it
    assert drives.read_sdo(timeout=5.0).values == expected


def test_a_late_upload_answer_is_not_taken_for_a_write_s(drives, sim):
    """The same late answer coming in while a write waits for its own: the write is
    asked once more (the same value: the node took the first one all the same)."""
    expected = drives.read().values
    _give_up_an_upload(drives, sim)
    drives.remote[1].sdo.RESPONSE_TIMEOUT = 5.0
    try:
        drives.sdo_write(1, 0x6060, 1)             # profile position, as it is already
    finally:
        drives.remote[1].sdo.RESPONSE_TIMEOUT = drives.timeout
    sim.call("clear")              # (the heartbeats came 1 s late too: until they are back)
    assert eventually(lambda: drives.read_sdo(timeout=5.0)).values == expected
    assert drives.sdo_read(1, 0x6060) == 1


def test_lost_tpdos_cost_a_sync_not_the_reading(drives, sim):
    """A flaky bus (10 % of TPDOs lost): readings still succeed, each from one SYNC at
    which every node answered, and the extra SYNCs are counted."""
    before = drives.read()
    sim.call("faults", {"drop_prob": 0.1})
    seqs = []
    for _ in range(20):
        s = drives.read(timeout=2.0)
        assert s.values == before.values and s.info["source"] == "tpdo"
        seqs.append(s.seq)
    assert drives.resyncs > 0 and seqs == sorted(set(seqs))


def test_late_answers_within_timeout_are_fine(drives, sim):
    expected = drives.read().values
    sim.call("faults", {"late_s": 0.15})
    # a timeout 20x the lateness: the test is about late answers, not about how busy
    # the machine running it is
    assert drives.read(timeout=3.0).values == expected
    assert drives.read_sdo(timeout=3.0).values == expected


def test_tpdos_later_than_the_sync_window_answer_their_own_sync(drives, sim):
    """TPDOs three times later than a SYNC's first window (``sync_wait``, 0.05 s), and a
    window that closes at once (the reading thread descheduled through it): each reading
    is answered by the one SYNC it sent, none sends another, and no TPDO comes in
    outside the window of the SYNC it answers (the SDO answer a node gives after the
    window proves its TPDO came first, so it is waited for, never left to a later SYNC)."""
    expected = drives.read().values
    resyncs, unsolicited = drives.resyncs, drives.unsolicited_tpdos
    sim.call("faults", {"late_s": 0.15})
    syncs = []
    for wait in (drives.sync_wait, drives.sync_wait, 0.0, 0.0):
        drives.sync_wait = wait
        s = drives.read(timeout=3.0)
        assert s.values == expected and s.info["source"] == "tpdo"
        syncs.append(s.info["sync"])
    assert syncs == list(range(syncs[0], syncs[0] + 4))          # one SYNC per reading
    sim.call("clear")
    assert sim.call("drain")
    assert drives.read_sdo().values == expected       # barrier: every TPDO sent is in
    assert drives.resyncs == resyncs
    assert drives.unsolicited_tpdos == unsolicited


def test_a_tpdo_given_up_never_answers_a_later_sync(drives, sim):
    """Late (0.15 s) and lost (20 %) TPDOs together: every reading still succeeds, from
    one SYNC at which every node answered; a SYNC is repeated only once its missing
    TPDOs are proven lost, so none of them comes in later (where it could be taken
    for a newer SYNC's)."""
    expected = drives.read().values
    unsolicited = drives.unsolicited_tpdos
    sim.call("faults", {"late_s": 0.15, "drop_prob": 0.2})
    for _ in range(6):
        s = drives.read(timeout=10.0)
        assert s.values == expected and s.info["source"] == "tpdo"
    sim.call("clear")
    assert sim.call("drain")
    assert drives.read_sdo().values == expected       # barrier: every TPDO sent is in
    assert drives.unsolicited_tpdos == unsolicited


def test_late_answers_beyond_timeout_are_timeouts(drives, sim):
    expected = drives.read().values
    sim.call("faults", {"late_s": 0.8})
    with pytest.raises(DeviceTimeout) as err:
        drives.read(timeout=0.2)
    assert err.value.device.startswith("canopen node ")
    with pytest.raises(DeviceTimeout) as err:
        drives.read_sdo(timeout=0.2)
    assert err.value.device.startswith("canopen node ")
    sim.call("clear")
    assert sim.call("drain")
    assert eventually(drives.read_sdo).values == expected      # barrier: late frames are through
    assert eventually(drives.read).values == expected


def test_plain_canopen_master_talks_to_simulated_drive(sim):
    ep = dict(sim.endpoint)
    ep.pop("nodes")
    network = canopen.Network()
    network.connect(**ep)
    try:
        node = network.add_node(2, str(EDS_PATH))
        assert node.sdo[0x1000].raw == 0x00020192
        assert node.sdo.upload(0x6064, 0) == round(START[1] * RES).to_bytes(4, "little", signed=True)
        assert node.sdo["Position actual value"].raw == round(START[1] * RES)
    finally:
        network.disconnect()


def test_wrong_profile_and_bad_config_are_named(sim):
    enc = CanopenEncoders.from_endpoint(sim.endpoint, RES, timeout=1.0)
    with pytest.raises(DeviceError, match="canopen node 1: device type 0x00020192 is not CiA"):
        enc.open()
    assert not enc.is_open
    with pytest.raises(ConfigError, match="nodes"):
        CanopenActuators([1, 1], RES)
    with pytest.raises(ConfigError, match="resolution"):
        CanopenActuators([1, 2], [RES])
    drv = CanopenActuators.from_endpoint(sim.endpoint, RES)
    drv.close()
    with drv:
        with pytest.raises(ValueError, match="qm_targets"):
            drv.move_to([0.0])
    drv.close()                                                # idempotent
    assert emcy_text(0x5530).startswith("non-volatile") and emcy_text(0x1234).startswith("unknown EMCY 0x1234")


def test_cia406_encoders_read_and_preset():
    sim = SimProcess(nodes=[5, 6], positions=[0.25, -0.5], resolution=4096.0, profile="cia406")
    try:
        with CanopenEncoders.from_endpoint(sim.endpoint, 4096.0, timeout=1.0) as enc:
            sample = enc.read()
            assert sample.values == {"qm1": 0.25, "qm2": -0.5}
            assert enc.read_sdo().values == sample.values
            sim.call("move", 0, 0.5)
            eventually(lambda: _require(sim.call("position", 0) == 0.5))
            assert enc.read().values["qm1"] == 0.5
            enc.preset([1.0, 2.0])
            assert enc.read().values == {"qm1": 1.0, "qm2": 2.0}
    finally:
        sim.close()


def _require(condition):
    if not condition:
        raise DeviceError("not yet")


def test_hub_forwards_to_others_and_survives_disconnects():
    with SocketcandHub() as hub:
        a, b, c = (can.Bus(**hub.endpoint) for _ in range(3))
        try:
            a.send(can.Message(arbitration_id=0x181, data=[1, 2, 0xFF], is_extended_id=False))
            a.send(can.Message(arbitration_id=0x1ABCDEF, data=[], is_extended_id=True))
            for bus in (b, c):
                first, second = bus.recv(2), bus.recv(2)
                assert (first.arbitration_id, bytes(first.data), first.is_extended_id) == (0x181, b"\x01\x02\xff", False)
                assert (second.arbitration_id, second.dlc, second.is_extended_id) == (0x1ABCDEF, 0, True)
            assert a.recv(0.2) is None                          # no echo
            b.shutdown()
            c.send(can.Message(arbitration_id=0x80, data=[], is_extended_id=False))
            assert a.recv(2).arbitration_id == 0x80
        finally:
            a.shutdown(), c.shutdown()


def test_config_wiring_and_robot_increments_hook():
    from drivers.config import CanopenConfig
    from drivers.canopen_drives import canopen_device
    from drivers.sim.axis import SimAxis
    from drivers.sim.cia402_drive import start_canopen_sim
    axes = [SimAxis(0.0), SimAxis(0.0)]
    with start_canopen_sim(axes, [7, 8], 100.0, increments=lambda i, res: 1000 * (i + 1) + 1) as sim:
        ep = sim.endpoint
        cfg = CanopenConfig(interface="socketcand", channel="can0", nodes=(7, 8), increments_per_unit=(100.0, 100.0),
                            host=ep["host"], port=ep["port"], profile_velocity=(1.0, 1.0),
                            profile_acceleration=(4.0, 4.0))
        with canopen_device(cfg) as drv:
            assert isinstance(drv, CanopenActuators)
            assert drv.read().values == {"qm1": 10.01, "qm2": 20.01}
            assert drv.sdo_read(8, 0x6081) == 100 and drv.sdo_read(8, 0x6083) == 400


def test_a_lost_bus_is_a_device_error_not_a_thread_traceback(caplog):
    """The socketcand server goes away under an open bus with frames it never read (the
    simulator's process ends, a real server dies): the connection is reset and
    python-can's receive thread fails on the socket. The station hears it as the
    device's one-line error at its next call; nothing escapes the thread as an unhandled
    exception (its traceback would land on the operator's terminal) and canopen logs no
    error of its own."""
    import os
    import signal
    import threading

    escaped = []
    hook = threading.excepthook
    threading.excepthook = lambda args: escaped.append(args.exc_value)
    proc = SimProcess(nodes=[1], positions=[0.0], resolution=RES)
    try:
        drv = CanopenActuators.from_endpoint(proc.endpoint, RES, timeout=1.0)
        drv.open()
        try:
            os.kill(proc.proc.pid, signal.SIGSTOP)      # reads nothing from now on
            for _ in range(200):
                drv.network.send_message(0x80, b"")
            time.sleep(0.2)
            proc.proc.kill()                             # unread frames: a reset
            proc.proc.join(10)
            with pytest.raises(DeviceError) as err:
                end = time.monotonic() + 10
                while time.monotonic() < end:
                    drv.read()
                    time.sleep(0.05)
            assert "\n" not in str(err.value) and "Traceback" not in str(err.value)
            time.sleep(0.3)
        finally:
            drv.close()
    finally:
        threading.excepthook = hook
        proc.conn.close()
    assert not escaped, escaped
    assert not [r for r in caplog.records if r.name.startswith("canopen")
                and r.levelname == "ERROR"], caplog.text
    print(err.value)
