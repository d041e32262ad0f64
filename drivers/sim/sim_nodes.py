"""Simulated CANopen nodes: CiA 402 drives and CiA 406 encoders (the drivers' twin).

Each node is a canopen ``LocalNode`` (object dictionary from
``fixtures/eds/agebot_cia402.eds``) on a :class:`~drivers.sim.sim_network.SimNetwork`.
What a LocalNode does not do by itself is done here: TPDOs on SYNC (from the
node's own 0x1800/0x1A00, so a master may remap them), heartbeats (0x1017,
through the fault plan), the CiA 402 state machine and set-point handshake on
controlword writes, target reached from a :class:`~drivers.sim.axis.SimAxis`,
EMCY on fault (``drive_fault_node`` of the fault plan goes to FAULT with EMCY
0x8611, following error, at its next set-point, once); a set-point outside the
axis's physical travel range (:class:`~drivers.sim.axis.AxisLimit`) puts it in
FAULT with EMCY 0x8612 (reference limit, manufacturer bytes ``TRVL``) and does not
move it.

Positions: increments = round(axis position [units] * resolution
[increments/unit]); 0x6081 in increments/s and 0x6083 in increments/s^2.
"""
from __future__ import annotations

import logging
from pathlib import Path

import canopen
from canopen.objectdictionary import UNSIGNED32, ODVariable

from drivers.sim.axis import AxisLimit, SimAxis
from drivers.sim.faults import FaultPlan
from drivers.sim.sim_network import SimNetwork

log = logging.getLogger("drivers.sim")

EDS_PATH = Path(__file__).resolve().parents[2] / "fixtures" / "eds" / "agebot_cia402.eds"
SW = {"SWITCH ON DISABLED": 0x0040, "READY TO SWITCH ON": 0x0021, "SWITCHED ON": 0x0023,
      "OPERATION ENABLED": 0x0027, "QUICK STOP ACTIVE": 0x0007, "FAULT": 0x0008}


class SimNode:
    """One simulated node: a LocalNode with TPDOs on SYNC from its own PDO objects."""

    def __init__(self, network: SimNetwork, node_id: int, axis: SimAxis, resolution: float,
                 plan: FaultPlan, od=None, increments=None, check=None):
        self.id, self.axis, self.resolution, self.plan = node_id, axis, float(resolution), plan
        self._increments = increments
        self._check = check        # the robot's physical limits, asked before a state read
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
            if self._check is not None:
                self._check()
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
        try:
            self.axis.command(target / self.resolution, vel / self.resolution if vel else None,
                              acc / self.resolution if acc else None)
        except AxisLimit as e:      # the drive's limit switch / software position limit
            log.warning("node %d: %s", self.id, e)
            self.fault(0x8612, register=0x21, data=b"TRVL")   # manufacturer bytes: travel
            return
        self.ack = True

    def fault(self, code: int, register: int = 0x01, data: bytes = b"") -> None:
        """Go to FAULT, stop the axis, log 0x1003 and send EMCY ``code`` (with up to 5
        manufacturer bytes ``data``)."""
        self.axis.stop()
        self.state, self.ack = "FAULT", False
        self.store(0x1001, register)
        self.store(0x603F, code)
        history = [self.value(0x1003, s) for s in range(1, 4)]
        for sub, v in enumerate([code] + history, start=1):
            self.store(0x1003, v, sub)
        self.store(0x1003, min(4, self.value(0x1003, 0) + 1), 0)
        self.node.emcy.send(code, register, data[:5])


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

    def __init__(self, network, node_id, axis, resolution, plan, increments=None, check=None):
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
