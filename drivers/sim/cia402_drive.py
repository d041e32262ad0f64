"""Simulated CANopen nodes: CiA 402 drives and CiA 406 encoders (the drivers' twin).

Each node is a canopen ``LocalNode`` (object dictionary from
``fixtures/eds/agebot_cia402.eds``) on one ``canopen.Network`` connected to
any python-can bus (normally the socketcand hub). What a LocalNode does not do
by itself is done here: TPDOs on SYNC (from the node's own 0x1800/0x1A00, so a
master may remap them), heartbeats (0x1017, through the fault plan), the CiA 402
state machine and set-point handshake on controlword writes, target reached
from a :class:`~drivers.sim.axis.SimAxis`, EMCY on fault.

Faults (:class:`~drivers.sim.faults.FaultPlan`, consulted on the wire):
``silent_nodes`` send nothing and ignore SDO requests; ``drive_fault_node``
goes to FAULT with EMCY 0x8611 (following error) at its next set-point (once:
the plan field is reset to 0 when it fires); ``drop_prob`` and
``corrupt_prob`` drop TPDOs (a corrupted CAN frame never passes the CRC);
``late_s`` delays every frame a node sends.

Positions: increments = round(axis position [units] * resolution
[increments/unit]); 0x6081 in increments/s and 0x6083 in increments/s^2.
"""
from __future__ import annotations

import collections
import functools
import logging
import threading
import time
from pathlib import Path

import can
import canopen
from canopen.objectdictionary import UNSIGNED32, ODVariable

from drivers.sim.axis import SimAxis
from drivers.sim.faults import FaultPlan

log = logging.getLogger("drivers.sim.canopen")
EDS_PATH = Path(__file__).resolve().parents[2] / "fixtures" / "eds" / "agebot_cia402.eds"
SW = {"SWITCH ON DISABLED": 0x0040, "READY TO SWITCH ON": 0x0021, "SWITCHED ON": 0x0023,
      "OPERATION ENABLED": 0x0027, "QUICK STOP ACTIVE": 0x0007, "FAULT": 0x0008}


class _Periodic:
    """A periodic frame (heartbeat) sent by the network's own thread, so faults apply."""

    def __init__(self, network, can_id, data, period):
        self.network, self.can_id, self.data, self.period = network, can_id, bytes(data or b""), period
        self.next_t = time.monotonic()

    def update(self, data):
        self.data = bytes(data)

    def stop(self):
        self.network._remove_periodic(self)


class SimNetwork(canopen.Network):
    """canopen Network whose outgoing frames pass the fault plan and a delay line
    (one transmit thread, first in first out, ``plan.late_s`` seconds late)."""

    def __init__(self, plan: FaultPlan):
        super().__init__()
        self.plan = plan
        self._cv = threading.Condition(threading.RLock())
        self._queue: collections.deque = collections.deque()
        self._periodic: list[_Periodic] = []
        self._busy = False
        self._stop = False
        self._tx = threading.Thread(target=self._run, name="sim-canopen-tx", daemon=True)

    def connect(self, *args, **kwargs):
        super().connect(*args, **kwargs)
        self._tx.start()
        return self

    def disconnect(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        if self._tx.is_alive():
            self._tx.join(5.0)
        self.nodes.clear()            # LocalNode PDOs cannot be stopped by Network.disconnect
        super().disconnect()

    def notify(self, can_id, data, timestamp):
        if 0x600 < can_id < 0x680 and can_id - 0x600 in self.plan.silent_nodes:
            return                    # a silent node does not even hear its SDO requests
        super().notify(can_id, data, timestamp)

    def send_message(self, can_id: int, data, remote: bool = False) -> None:
        plan = self.plan
        if (can_id & 0x7F) in plan.silent_nodes:
            return
        if 0x180 <= can_id < 0x500 and (plan.chance(plan.drop_prob) or plan.chance(plan.corrupt_prob)):
            return
        with self._cv:
            if len(self._queue) < 10000:
                self._queue.append((time.monotonic() + max(0.0, plan.late_s), can_id, bytes(data)))
                self._cv.notify_all()

    def send_periodic(self, can_id, data, period, remote=False):
        task = _Periodic(self, can_id, data, period)
        with self._cv:
            self._periodic.append(task)
            self._cv.notify_all()
        return task

    def _remove_periodic(self, task):
        with self._cv:
            if task in self._periodic:
                self._periodic.remove(task)

    def drain(self, timeout: float = 10.0) -> bool:
        """Wait until every queued frame is on the bus; False on timeout."""
        end = time.monotonic() + timeout
        with self._cv:
            while self._queue or self._busy:
                if not self._cv.wait(max(0.0, end - time.monotonic())):
                    return False
        return True

    def _run(self):
        while True:
            with self._cv:
                if self._stop:
                    return
                now = time.monotonic()
                for task in list(self._periodic):
                    if task.next_t <= now:
                        task.next_t = max(task.next_t + task.period, now)
                        self.send_message(task.can_id, task.data)
                wake = min([t.next_t for t in self._periodic] + [now + 0.1])
                if not self._queue or self._queue[0][0] > now:
                    if self._queue:
                        wake = min(wake, self._queue[0][0])
                    self._cv.wait(max(0.0, wake - now))
                    continue
                _, can_id, data = self._queue.popleft()
                self._busy = True
            try:
                self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=can_id > 0x7FF))
            except (can.CanError, OSError) as e:
                log.warning("sim CANopen: cannot send 0x%03X: %s", can_id, e)
            finally:
                with self._cv:
                    self._busy = False
                    self._cv.notify_all()


class SimNode:
    """One simulated node: a LocalNode with TPDOs on SYNC from its own PDO objects."""

    def __init__(self, network: SimNetwork, node_id: int, axis: SimAxis, resolution: float,
                 plan: FaultPlan, od=None, increments=None):
        self.id, self.axis, self.resolution, self.plan = node_id, axis, float(resolution), plan
        self._increments = increments
        self.node = canopen.LocalNode(node_id, od or canopen.import_od(str(EDS_PATH), node_id))
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        network.add_node(self.node)
        self._syncs = 0

    def value(self, index: int, sub: int = 0):
        obj = self.node.object_dictionary[index]
        obj = obj[sub] if not isinstance(obj, ODVariable) else obj
        return obj.decode_raw(self.node.get_data(index, sub))

    def store(self, index: int, value, sub: int = 0) -> None:
        obj = self.node.object_dictionary[index]
        obj = obj[sub] if not isinstance(obj, ODVariable) else obj
        self.node.data_store.setdefault(index, {})[sub] = obj.encode_raw(value)

    def increments(self) -> int:
        """Encoder increments now: the ``increments()`` given (e.g. the simulated robot's,
        with noise) or ``round(axis position * resolution)``."""
        if self._increments is not None:
            return int(self._increments())
        return round(self.axis.position() * self.resolution)

    def boot(self) -> None:
        self.node.nmt.send_command(0x81)      # reset node: sends the boot-up frame
        self.node.nmt.send_command(0x80)      # to PRE-OPERATIONAL: heartbeat per 0x1017

    def on_sync(self) -> None:
        if self.node.nmt.state != "OPERATIONAL":
            return
        cob_id, ttype = self.value(0x1800, 1), self.value(0x1800, 2)
        if cob_id & 0x80000000 or not 1 <= ttype <= 240:
            return
        self._syncs += 1
        if self._syncs % ttype:
            return
        data = b""
        for sub in range(1, self.value(0x1A00, 0) + 1):
            entry = self.value(0x1A00, sub)
            data += self.node.get_data(entry >> 16, (entry >> 8) & 0xFF)[:(entry & 0xFF) // 8]
        self.node.network.send_message(cob_id & 0x7FF, data[:8])

    def _on_read(self, index, subindex, od):
        return None

    def _on_write(self, index, subindex, od, data):
        return None


class SimDrive402(SimNode):
    """A CiA 402 drive in profile position mode moving ``axis``."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.state = "SWITCH ON DISABLED"
        self.controlword = 0
        self.ack = False

    def statusword(self) -> int:
        sw = SW[self.state] | 0x0200 | (0x0010 if self.state != "SWITCH ON DISABLED" else 0)
        if self.axis.target_reached():
            sw |= 0x0400
        if self.ack:
            sw |= 0x1000
        return sw

    def _on_read(self, index, subindex, od):
        if index == 0x6041:
            return self.statusword()
        if index == 0x6064:
            return self.increments()
        if index == 0x6061:
            return self.value(0x6060)
        return None

    def _on_write(self, index, subindex, od, data):
        if index == 0x6040:
            self._controlword(int.from_bytes(data, "little"))

    def _controlword(self, cw: int) -> None:
        prev, self.controlword = self.controlword, cw
        state = self.state
        if state == "FAULT":
            if cw & 0x80 and not prev & 0x80:
                self.state = "SWITCH ON DISABLED"
                for index, value in ((0x1001, 0), (0x603F, 0)):
                    self.store(index, value)
                self.node.emcy.reset()
            return
        if not cw & 0x02:
            new = "SWITCH ON DISABLED"
        elif not cw & 0x04:
            new = "QUICK STOP ACTIVE" if state == "OPERATION ENABLED" else "SWITCH ON DISABLED"
        elif cw & 0x0F == 0x06:
            new = "READY TO SWITCH ON" if state != "QUICK STOP ACTIVE" else state
        elif cw & 0x0F == 0x07:
            new = "SWITCHED ON" if state in ("READY TO SWITCH ON", "OPERATION ENABLED") else state
        elif cw & 0x0F == 0x0F:
            ok = ("READY TO SWITCH ON", "SWITCHED ON", "QUICK STOP ACTIVE", "OPERATION ENABLED")
            new = "OPERATION ENABLED" if state in ok else state
        else:
            new = state
        if state == "OPERATION ENABLED" and new != state:
            self.axis.stop()
        self.state = new
        if new != "OPERATION ENABLED" or self.value(0x6060) != 1:
            self.ack = False
            return
        if cw & 0x0100:
            self.axis.stop()          # halt
        if not cw & 0x10:
            self.ack = False
        elif not prev & 0x10:
            self._new_setpoint(cw)

    def _new_setpoint(self, cw: int) -> None:
        if self.plan.drive_fault_node == self.id:
            self.plan.update(drive_fault_node=0)
            self.fault(0x8611, register=0x21)
            return
        target = self.value(0x607A) + (round(self.axis.target * self.resolution) if cw & 0x40 else 0)
        vel, acc = self.value(0x6081), self.value(0x6083)
        self.axis.command(target / self.resolution, vel / self.resolution if vel else None,
                          acc / self.resolution if acc else None)
        self.ack = True

    def fault(self, code: int, register: int = 0x01) -> None:
        """Go to FAULT, stop the axis, log 0x1003 and send EMCY ``code``."""
        self.axis.stop()
        self.state, self.ack = "FAULT", False
        self.store(0x1001, register)
        self.store(0x603F, code)
        history = [self.value(0x1003, s) for s in range(1, 4)]
        for sub, v in enumerate([code] + history, start=1):
            self.store(0x1003, v, sub)
        self.store(0x1003, min(4, self.value(0x1003, 0) + 1), 0)
        self.node.emcy.send(code, register)


def cia406_od(node_id: int):
    """CiA 406 multi-turn encoder dictionary: the drive EDS's communication part
    plus preset 0x6003 and position value 0x6004 (TPDO1 maps 0x60040020)."""
    od = canopen.import_od(str(EDS_PATH), node_id)
    for index in [i for i in od.indices if 0x6000 <= i < 0x7000]:
        del od[index]
    od[0x1000].default = 0x00020196
    for index, name, access in ((0x6003, "Preset value", "rw"), (0x6004, "Position value", "ro")):
        v = ODVariable(name, index)
        v.data_type, v.access_type, v.default, v.pdo_mappable = UNSIGNED32, access, 0, index == 0x6004
        od.add_object(v)
    od[0x1A00][0].default, od[0x1A00][1].default, od[0x1A00][2].default = 1, 0x60040020, 0
    return od


class SimEncoder406(SimNode):
    """A read-only CiA 406 encoder on ``axis`` (moved by the robot's own controller)."""

    def __init__(self, network, node_id, axis, resolution, plan, increments=None):
        super().__init__(network, node_id, axis, resolution, plan, od=cia406_od(node_id), increments=increments)
        self.offset = 0

    def _on_read(self, index, subindex, od):
        if index == 0x6004:
            return (self.increments() + self.offset) & 0xFFFFFFFF
        return None

    def _on_write(self, index, subindex, od, data):
        if index == 0x6003:
            preset = int.from_bytes(data, "little")
            self.offset = preset - self.increments()


class SimulatedDrives:
    """Simulated CANopen nodes sharing one bus connection.

    bus:        python-can ``can.Bus`` keyword arguments, e.g. ``hub.endpoint``
                (``interface="socketcand", host, port, channel``).
    nodes:      node ids, one per axis.
    axes:       one :class:`SimAxis` per node (actuator units).
    resolution: increments per actuator unit, one number or one per node.
    plan:       the shared :class:`FaultPlan` (a fresh all-off plan if None).
    profile:    ``"cia402"`` (drives) or ``"cia406"`` (read-only encoders).
    increments: optional ``increments(i, resolution) -> int`` giving axis ``i``'s encoder
                value (e.g. ``SimulatedAgebot.encoder_increments``, with noise); default
                ``round(axes[i].position() * resolution)``.
    """

    def __init__(self, bus: dict, nodes, axes, resolution, plan: FaultPlan | None = None,
                 profile: str = "cia402", increments=None):
        self.increments = increments
        self.bus_config = dict(bus)
        self.node_ids = [int(n) for n in nodes]
        self.axes = list(axes)
        res = [resolution] * len(self.node_ids) if isinstance(resolution, (int, float)) else list(resolution)
        if len(self.axes) != len(self.node_ids) or len(res) != len(self.node_ids):
            raise ValueError("nodes, axes and resolution must have one entry per node")
        if profile not in ("cia402", "cia406"):
            raise ValueError(f"profile: 'cia402' or 'cia406', got {profile!r}")
        self.resolution, self.profile = res, profile
        self.plan = plan if plan is not None else FaultPlan()
        self.network: SimNetwork | None = None
        self.nodes: dict[int, SimNode] = {}

    def start(self) -> "SimulatedDrives":
        if self.network is not None:
            return self
        config = dict(self.bus_config)
        if config.get("interface") == "socketcand":
            config.setdefault("tcp_tune", True)      # no Nagle delay between back-to-back frames
        network = SimNetwork(self.plan).connect(**config)
        kind = SimDrive402 if self.profile == "cia402" else SimEncoder406
        for i, (nid, axis, res) in enumerate(zip(self.node_ids, self.axes, self.resolution)):
            inc = None if self.increments is None else functools.partial(self.increments, i, res)
            self.nodes[nid] = kind(network, nid, axis, res, self.plan, increments=inc)
        network.subscribe(0x80, self._on_sync)
        self.network = network
        for node in self.nodes.values():
            node.boot()
        return self

    def _on_sync(self, can_id, data, timestamp):
        for node in self.nodes.values():
            node.on_sync()

    def drain(self, timeout: float = 10.0) -> bool:
        """Wait until every delayed frame has been sent."""
        return self.network.drain(timeout) if self.network is not None else True

    def stop(self) -> None:
        network, self.network = self.network, None
        if network is not None:
            network.disconnect()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


class CanopenSim:
    """A socketcand hub plus simulated nodes on it; ``endpoint`` is what a client needs
    (the ``canopen`` record of ``app.py simulate --endpoints``)."""

    def __init__(self, hub, drives: SimulatedDrives):
        self.hub, self.drives = hub, drives

    @property
    def endpoint(self) -> dict:
        return dict(self.hub.endpoint, nodes=list(self.drives.node_ids))

    def stop(self) -> None:
        self.drives.stop()
        self.hub.stop()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def start_canopen_sim(axes, nodes, resolution, plan: FaultPlan | None = None, *, host: str = "127.0.0.1",
                      port: int = 0, channel: str = "can0", profile: str = "cia402",
                      increments=None) -> CanopenSim:
    """Start a socketcand hub on ``host:port`` (0: ephemeral) and the simulated nodes
    on it, in this process (threads). Arguments as :class:`SimulatedDrives`.
    Returns a :class:`CanopenSim` (``.endpoint``, ``.drives``, ``.hub``, ``.stop()``)."""
    from drivers.sim.socketcand_hub import SocketcandHub
    hub = SocketcandHub(host, port, channel).start()
    try:
        drives = SimulatedDrives(hub.endpoint, nodes, axes, resolution, plan, profile, increments).start()
    except BaseException:
        hub.stop()
        raise
    return CanopenSim(hub, drives)


def run_sim_process(conn, nodes=(1, 2, 3, 4), positions=None, resolution=10000.0, *, velocity=2.0,
                    acceleration=8.0, profile="cia402", port=0, seed=None) -> None:
    """Entry of a separate simulator process (``multiprocessing.Process(target=...)``).

    Starts hub + nodes, sends ``("ready", endpoint)`` on ``conn``, then serves
    requests until ``("stop",)`` or EOF; each gets ``("ok", result)`` or ``("error", text)``:
    ``("faults", {field: value})``, ``("clear",)``, ``("drain",)``, ``("plan",)``,
    ``("position", i)`` (axis i, units), ``("move", i, target)`` (the robot's own controller).
    """
    positions = list(positions) if positions is not None else [0.0] * len(nodes)
    axes = [SimAxis(p, velocity, acceleration) for p in positions]
    sim = start_canopen_sim(axes, nodes, resolution, FaultPlan(seed=seed), port=port, profile=profile)
    plan = sim.drives.plan
    try:
        conn.send(("ready", sim.endpoint))
        while True:
            try:
                req = conn.recv()
            except (EOFError, OSError):
                break
            if req[0] == "stop":
                conn.send(("ok", None))
                break
            try:
                result = {"faults": lambda: plan.update(**req[1]), "clear": plan.clear,
                          "drain": sim.drives.drain, "plan": plan.as_dict,
                          "position": lambda: axes[req[1]].position(),
                          "move": lambda: axes[req[1]].command(req[2])}[req[0]]()
                conn.send(("ok", result))
            except Exception as e:
                conn.send(("error", f"{type(e).__name__}: {e}"))
    finally:
        sim.stop()
