"""CANopen actuators (CiA 402 drives) and encoders (CiA 406) over python-can + canopen.

Every node is a canopen ``RemoteNode`` on one ``canopen.Network``; SDO, PDO and
NMT are the library's. Positions are sampled together: the master sends one
SYNC and waits for every node's TPDO1 (transmission type 1, mapping statusword
0x6041 + position actual value 0x6064, or position value 0x6004 for an
encoder). A TPDO is attributed to the last SYNC sent before it arrived (the
synchronous window is the read timeout); a node whose TPDO does not come in
time gives :class:`DeviceTimeout` naming it, never an older value. Heartbeats
(producer time 0x1017, set by the master) are watched: a silent node is
``"canopen node 3: heartbeat lost ..."``. A drive fault raises
:class:`ProtocolError` carrying the EMCY code and its text.

Units: positions in actuator units ``Qm`` = increments / ``resolution``
(increments per actuator unit, one for all nodes or one per node); velocities
in units/s, accelerations in units/s^2, times in seconds.
"""
from __future__ import annotations

import contextlib
import functools
import math
import threading
import time
from collections.abc import Sequence

import can
import canopen
from canopen.objectdictionary import (INTEGER8, INTEGER32, UNSIGNED8, UNSIGNED16, UNSIGNED32,
                                      ObjectDictionary, ODRecord, ODVariable)
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from calibration.errors import ConfigError
from drivers.base import Device, Sample
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

#: EMCY error codes (CiA 301 / CiA 402) the station names; others show as hex.
EMCY_TEXT = {
    0x0000: "error reset / no error", 0x1000: "generic error",
    0x2310: "continuous over-current", 0x2320: "short circuit at motor side",
    0x3210: "DC link over-voltage", 0x3220: "DC link under-voltage",
    0x4210: "excess temperature device", 0x4310: "drive temperature too high",
    0x5530: "non-volatile memory (EEPROM) error", 0x6320: "parameter error",
    0x7305: "incremental sensor 1 fault", 0x8110: "CAN overrun (objects lost)",
    0x8130: "life guard or heartbeat error", 0x8611: "following error",
    0x8612: "reference limit", 0xFF00: "device specific",
}
NMT_OPERATIONAL = 5
_SDO_POLL_S = 0.005


def emcy_text(code: int) -> str:
    """Text of an EMCY error code; unknown codes as ``unknown EMCY 0x1234 (<class>)``."""
    if code in EMCY_TEXT:
        return EMCY_TEXT[code]
    cls = canopen.emcy.EmcyError(code, 0, b"", 0).get_desc()
    return f"unknown EMCY 0x{code:04X}" + (f" ({cls.lower()})" if cls else "")


def state_name(sw: int) -> str:
    """CiA 402 state of a statusword."""
    for mask, value, name in ((0x4F, 0x00, "NOT READY TO SWITCH ON"), (0x4F, 0x40, "SWITCH ON DISABLED"),
                              (0x6F, 0x21, "READY TO SWITCH ON"), (0x6F, 0x23, "SWITCHED ON"),
                              (0x6F, 0x27, "OPERATION ENABLED"), (0x6F, 0x07, "QUICK STOP ACTIVE"),
                              (0x4F, 0x0F, "FAULT REACTION ACTIVE"), (0x4F, 0x08, "FAULT")):
        if sw & mask == value:
            return name
    return f"UNKNOWN (0x{sw:04X})"


def standard_od() -> ObjectDictionary:
    """The standard objects the station uses (CiA 301, 402, 406); no vendor EDS needed."""
    od = ObjectDictionary()

    def var(index, sub, name, dtype, access="rw"):
        v = ODVariable(name, index, sub)
        v.data_type, v.access_type = dtype, access
        return v
    for index, name, dtype, access in (
            (0x1000, "Device type", UNSIGNED32, "ro"), (0x1001, "Error register", UNSIGNED8, "ro"),
            (0x1017, "Producer heartbeat time", UNSIGNED16, "rw"), (0x603F, "Error code", UNSIGNED16, "ro"),
            (0x6040, "Controlword", UNSIGNED16, "rw"), (0x6041, "Statusword", UNSIGNED16, "ro"),
            (0x6060, "Modes of operation", INTEGER8, "rw"), (0x6061, "Modes of operation display", INTEGER8, "ro"),
            (0x6064, "Position actual value", INTEGER32, "ro"), (0x607A, "Target position", INTEGER32, "rw"),
            (0x6081, "Profile velocity", UNSIGNED32, "rw"), (0x6083, "Profile acceleration", UNSIGNED32, "rw"),
            (0x6003, "Preset value", UNSIGNED32, "rw"), (0x6004, "Position value", UNSIGNED32, "ro")):
        od.add_object(var(index, 0, name, dtype, access))
    comm, mapping = ODRecord("TPDO1 communication parameter", 0x1800), ODRecord("TPDO1 mapping parameter", 0x1A00)
    for sub, name, dtype in ((0, "Highest sub-index", UNSIGNED8), (1, "COB-ID", UNSIGNED32),
                             (2, "Transmission type", UNSIGNED8), (3, "Inhibit time", UNSIGNED16),
                             (5, "Event timer", UNSIGNED16)):
        comm.add_member(var(0x1800, sub, name, dtype))
    mapping.add_member(var(0x1A00, 0, "Number of mapped objects", UNSIGNED8))
    for sub in range(1, 9):
        mapping.add_member(var(0x1A00, sub, f"Mapped object {sub}", UNSIGNED32))
    od.add_object(comm)
    od.add_object(mapping)
    return od


class CanopenNodes(Device):
    """Common part of the CANopen devices: network, NMT, heartbeat consumer, EMCY,
    SYNC + TPDO sampling and SDO fallback. Subclasses set the profile.

    nodes:             node ids (1..127), one per channel ``qm1..qmN``.
    resolution:        increments per actuator unit, one number or one per node.
    interface, channel, bus_options: python-can ``can.Bus`` arguments, e.g.
                       ``interface="socketcand", channel="can0", bus_options={"host": ..., "port": ...}``.
    timeout:           seconds for one SDO answer and for one SYNC's TPDOs.
    heartbeat_ms:      producer heartbeat time written to 0x1017 (ms).
    heartbeat_timeout: seconds without heartbeat before a node is lost (default 5 periods).
    read_via:          ``"tpdo"`` (SYNC + TPDO, default) or ``"sdo"`` (SDO upload per node).
    """

    profile = 0x0192                      # low word of 0x1000
    position_object = 0x6064
    tpdo_objects: tuple[tuple[int, int], ...] = ((0x6041, 16), (0x6064, 32))

    def __init__(self, nodes: Sequence[int], resolution: float | Sequence[float], *,
                 interface: str = "socketcan", channel: str = "can0", bus_options: dict | None = None,
                 timeout: float = 1.0, heartbeat_ms: int = 100, heartbeat_timeout: float | None = None,
                 read_via: str = "tpdo", name: str = "canopen"):
        super().__init__(name, timeout)
        self.nodes = [int(n) for n in nodes]
        if not self.nodes or len(set(self.nodes)) != len(self.nodes) or not all(1 <= n <= 127 for n in self.nodes):
            raise ConfigError(f"need distinct node ids in 1..127, got {list(nodes)}", key="nodes")
        res = [float(resolution)] * len(self.nodes) if isinstance(resolution, (int, float)) else list(resolution)
        if len(res) != len(self.nodes) or not all(math.isfinite(r) and r != 0 for r in res):
            raise ConfigError(f"need one finite non-zero value per node, got {resolution!r}", key="resolution")
        if read_via not in ("tpdo", "sdo"):
            raise ConfigError(f"must be 'tpdo' or 'sdo', got {read_via!r}", key="read_via")
        self.resolution = res
        self.channels = tuple(f"qm{i + 1}" for i in range(len(self.nodes)))
        self.bus_config = dict(bus_options or {}, interface=interface, channel=channel)
        if interface == "socketcand":   # TCP_NODELAY/QUICKACK: else Nagle holds frames ~40 ms
            self.bus_config.setdefault("tcp_tune", True)
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_timeout = heartbeat_timeout or 5 * self.heartbeat_ms / 1000.0
        self.read_via = read_via
        self.network: canopen.Network | None = None
        self.remote: dict[int, canopen.RemoteNode] = {}
        self._cv = threading.Condition()
        self._last_hb: dict[int, float] = {}
        self._hb_state: dict[int, int] = {}
        self._emcy: dict[int, canopen.emcy.EmcyError | None] = {}
        self._sync_no = 0
        self._pending: set[int] = set()
        self._fresh: dict[int, tuple] = {}
        self.unsolicited_tpdos = 0        # TPDOs that came outside a SYNC window (late or extra)

    @classmethod
    def from_endpoint(cls, endpoint: dict, resolution, **options):
        """Build from an endpoint record as ``app.py simulate --endpoints`` writes it."""
        ep = dict(endpoint)
        nodes = ep.pop("nodes")
        return cls(nodes, resolution, interface=ep.pop("interface"), channel=ep.pop("channel", "can0"),
                   bus_options=ep, **options)

    @classmethod
    def from_config(cls, cfg, **options):
        """Build from a :class:`drivers.config.CanopenConfig` (its bus, nodes, resolutions,
        timeouts, heartbeat; profile velocity/acceleration for drives)."""
        bus = cfg.bus_kwargs()
        kw = dict(interface=bus.pop("interface"), channel=bus.pop("channel"), bus_options=bus,
                  timeout=cfg.sdo_timeout, heartbeat_ms=round(cfg.heartbeat_period * 1000),
                  heartbeat_timeout=cfg.heartbeat_timeout)
        if cls is CanopenActuators:
            kw.update(velocity=tuple(cfg.profile_velocity) or None,
                      acceleration=tuple(cfg.profile_acceleration) or None)
        return cls(cfg.nodes, cfg.increments_per_unit, **dict(kw, **options))

    def node_name(self, nid: int) -> str:
        return f"canopen node {nid}"

    # -- lifecycle ------------------------------------------------------------
    def _open_internal(self) -> None:
        self._last_hb.clear(), self._hb_state.clear(), self._emcy.clear()
        network = canopen.Network()
        try:
            network.connect(**self.bus_config)
        except (can.CanError, OSError, ValueError, ImportError) as e:
            raise DeviceError(f"cannot open CAN bus {self.bus_config}: {e}", device=self.name) from e
        self.network = network
        try:
            for nid in self.nodes:
                node = canopen.RemoteNode(nid, standard_od())
                network.add_node(node)
                node.sdo.RESPONSE_TIMEOUT = self.timeout
                node.nmt.add_heartbeat_callback(functools.partial(self._on_heartbeat, nid))
                node.emcy.add_callback(functools.partial(self._on_emcy, nid))
                self.remote[nid] = node
            for nid in self.nodes:
                self._configure(nid)
            for nid in self.nodes:
                self.remote[nid].nmt.state = "OPERATIONAL"
            self._await_operational()
        except BaseException:
            self._close_internal()
            raise

    def _configure(self, nid: int) -> None:
        node = self.remote[nid]
        with self._io(nid, "reading device type 0x1000"):
            dev_type = node.sdo[0x1000].raw
        if dev_type & 0xFFFF != self.profile:
            raise DeviceError(f"device type 0x{dev_type:08X} is not CiA {self.profile} (0x{self.profile:04X})",
                              device=self.node_name(nid))
        with self._io(nid, "configuring heartbeat and TPDO1"):
            node.nmt.state = "PRE-OPERATIONAL"
            node.sdo[0x1017].raw = self.heartbeat_ms
            tpdo = node.tpdo[1]
            tpdo.clear()
            for index, bits in self.tpdo_objects:
                tpdo.add_variable(index, 0, bits)
            tpdo.cob_id, tpdo.trans_type, tpdo.enabled = 0x180 + nid, 1, True
            tpdo.save()
            tpdo.add_callback(functools.partial(self._on_tpdo, nid))

    def _await_operational(self) -> None:
        limit = self.timeout + 3 * self.heartbeat_ms / 1000.0
        end = time.monotonic() + limit
        with self._cv:
            while any(self._hb_state.get(n) != NMT_OPERATIONAL for n in self.nodes):
                if not self._cv.wait(max(0.0, end - time.monotonic())):
                    late = [n for n in self.nodes if self._hb_state.get(n) != NMT_OPERATIONAL][0]
                    raise DeviceTimeout(f"no OPERATIONAL heartbeat within {limit:.2g} s after NMT start",
                                        device=self.node_name(late))

    def _close_internal(self) -> None:
        network, self.network = self.network, None
        self.remote = {}
        if network is not None:
            with contextlib.suppress(Exception):
                network.disconnect()

    # -- callbacks (receive thread) -----------------------------------------------
    def _on_heartbeat(self, nid: int, state: int) -> None:
        with self._cv:
            self._last_hb[nid] = time.monotonic()
            self._hb_state[nid] = state
            self._cv.notify_all()

    def _on_emcy(self, nid: int, entry) -> None:
        with self._cv:
            self._emcy[nid] = None if entry.code & 0xFF00 == 0 else entry
            self._cv.notify_all()

    def _on_tpdo(self, nid: int, pdo_map) -> None:
        values = tuple(var.raw for var in pdo_map.map)
        with self._cv:
            if nid in self._pending:
                self._fresh[nid] = values
                self._pending.discard(nid)
                self._cv.notify_all()
            else:
                self.unsolicited_tpdos += 1

    # -- health -------------------------------------------------------------------
    def check_health(self) -> None:
        """Raise if the receive thread died, a heartbeat is lost or a node left OPERATIONAL."""
        if self.network is None:
            raise DeviceError("device is not open", device=self.name)
        try:
            self.network.check()
        except Exception as e:
            raise DeviceError(f"CAN receive thread stopped: {e!r}", device=self.name) from e
        for nid in self.nodes:
            self._check_heartbeat(nid)

    def _check_heartbeat(self, nid: int, settle: bool = False) -> None:
        """With ``settle``, wait until a new heartbeat proves the node alive or it is overdue."""
        t0 = time.monotonic()
        with self._cv:
            while True:
                age = time.monotonic() - self._last_hb.get(nid, t0)
                if age > self.heartbeat_timeout:
                    raise DeviceTimeout(f"heartbeat lost (none for {age:.2f} s, limit {self.heartbeat_timeout:.2f} s)",
                                        device=self.node_name(nid))
                state = self._hb_state.get(nid)
                if state is not None and state != NMT_OPERATIONAL:
                    label = canopen.nmt.NMT_STATES.get(state, state)
                    raise DeviceError(f"left OPERATIONAL (heartbeat says {label})", device=self.node_name(nid))
                if not settle or self._last_hb.get(nid, 0.0) > t0:
                    return
                self._cv.wait(0.02)

    @contextlib.contextmanager
    def _io(self, nid: int, what: str):
        """Map canopen/python-can errors of one exchange with node ``nid`` to station errors."""
        try:
            yield
        except SdoAbortedError as e:
            raise ProtocolError(f"SDO abort while {what}", code=e.code,
                                text=SdoAbortedError.CODES.get(e.code, "unknown abort code"),
                                device=self.node_name(nid)) from e
        except SdoCommunicationError as e:
            raise DeviceTimeout(f"no SDO answer while {what} ({e})", device=self.node_name(nid)) from e
        except (can.CanError, OSError) as e:
            raise DeviceError(f"CAN bus error while {what}: {e}", device=self.node_name(nid)) from e

    # -- reading --------------------------------------------------------------------
    def sdo_read(self, nid: int, index: int, subindex: int = 0):
        """One SDO upload (decoded with the standard object dictionary)."""
        with self._io(nid, f"reading 0x{index:04X}:{subindex:02X}"):
            obj = self.remote[nid].sdo[index]
            return (obj[subindex] if subindex else obj).raw

    def sdo_write(self, nid: int, index: int, value, subindex: int = 0) -> None:
        with self._io(nid, f"writing 0x{index:04X}:{subindex:02X} = {value}"):
            obj = self.remote[nid].sdo[index]
            (obj[subindex] if subindex else obj).raw = value

    def _to_units(self, i: int, increments: int) -> float:
        return increments / self.resolution[i]

    def sync_sample(self, timeout: float | None = None) -> dict[int, tuple]:
        """Send one SYNC; return each node's TPDO values of that SYNC (``{nid: (values...)}``)."""
        timeout = self.timeout if timeout is None else float(timeout)
        self.check_health()
        with self._cv:
            self._sync_no += 1
            self._pending, self._fresh = set(self.nodes), {}
        try:
            self.network.sync.transmit()
        except (can.CanError, OSError) as e:
            raise DeviceError(f"cannot send SYNC: {e}", device=self.name) from e
        end = time.monotonic() + timeout
        with self._cv:
            while self._pending and self._cv.wait(max(0.0, end - time.monotonic())):
                pass
            missing, fresh = sorted(self._pending), self._fresh
            self._pending = set()
        for nid in missing:
            self._check_heartbeat(nid, settle=True)
        if missing:
            also = f" (also nodes {missing[1:]})" if len(missing) > 1 else ""
            raise DeviceTimeout(f"no TPDO for SYNC #{self._sync_no} within {timeout:.3g} s; stale sample refused"
                                f"{also}", device=self.node_name(missing[0]))
        return fresh

    def _read_internal(self, timeout: float) -> Sample:
        if self.read_via == "sdo":
            return self.read_sdo(timeout)
        fresh = self.sync_sample(timeout)
        t = time.monotonic()
        pos = [o for o, _ in self.tpdo_objects].index(self.position_object)
        raw = {nid: fresh[nid][pos] for nid in self.nodes}
        values = {ch: self._to_units(i, self._decode(raw[n])) for i, (ch, n) in enumerate(zip(self.channels, self.nodes))}
        return Sample(t, values, seq=self._sync_no, info=self._info(fresh, "tpdo"))

    def read_sdo(self, timeout: float | None = None) -> Sample:
        """Positions by one SDO upload per node (the fallback; not one common instant)."""
        if not self.is_open:
            raise DeviceError("device is not open", device=self.name)
        self.check_health()
        raw = {}
        for nid in self.nodes:
            self.remote[nid].sdo.RESPONSE_TIMEOUT = self.timeout if timeout is None else float(timeout)
            try:
                raw[nid] = self.sdo_read(nid, self.position_object)
            finally:
                self.remote[nid].sdo.RESPONSE_TIMEOUT = self.timeout
        values = {ch: self._to_units(i, self._decode(raw[n])) for i, (ch, n) in enumerate(zip(self.channels, self.nodes))}
        self._sync_no += 1
        return Sample(time.monotonic(), values, seq=self._sync_no, info={"source": "sdo", "increments": raw})

    def _decode(self, raw: int) -> int:
        return raw

    def _info(self, fresh: dict[int, tuple], source: str) -> dict:
        pos = [o for o, _ in self.tpdo_objects].index(self.position_object)
        return {"source": source, "sync": self._sync_no, "increments": {n: v[pos] for n, v in fresh.items()}}



class CanopenActuators(CanopenNodes):
    """CiA 402 drives in profile position mode (0x6060 = 1), one per actuator.

    Arguments as :class:`CanopenNodes`, plus ``velocity`` (units/s) and
    ``acceleration`` (units/s^2), one number or one per node, written to
    0x6081/0x6083 (in increments) at open when given. ``read()`` info carries each
    node's statusword and CiA 402 state. ``close()`` leaves the drives enabled
    (holding position): disabling could let an unbraked axis fall; call
    :meth:`disable` explicitly.
    """

    def __init__(self, nodes, resolution, *, velocity=None, acceleration=None, **options):
        super().__init__(nodes, resolution, **options)
        n = len(self.nodes)
        self.velocity, self.acceleration = (
            None if v is None else [float(v)] * n if isinstance(v, (int, float)) else [float(x) for x in v]
            for v in (velocity, acceleration))
        for key, v in (("velocity", self.velocity), ("acceleration", self.acceleration)):
            if v is not None and (len(v) != n or not all(math.isfinite(x) and x > 0 for x in v)):
                raise ConfigError(f"need one positive value (or one per node), got {v!r}", key=key)

    def _configure(self, nid: int) -> None:
        super()._configure(nid)
        i = self.nodes.index(nid)
        self.sdo_write(nid, 0x6060, 1)
        for index, value in ((0x6081, self.velocity), (0x6083, self.acceleration)):
            if value is not None:
                self.sdo_write(nid, index, round(abs(value[i] * self.resolution[i])))

    def _info(self, fresh, source):
        info = super()._info(fresh, source)
        info["statusword"] = {n: v[0] for n, v in fresh.items()}
        info["state"] = {n: state_name(v[0]) for n, v in fresh.items()}
        return info

    # -- CiA 402 state machine ------------------------------------------------------
    def statusword(self, nid: int) -> int:
        return self.sdo_read(nid, 0x6041)

    def _raise_fault(self, nid: int, sw: int) -> None:
        """Raise the drive's fault as ProtocolError with its EMCY code (or 0x603F)."""
        end = time.monotonic() + min(self.timeout, 0.5)
        with self._cv:
            while self._emcy.get(nid) is None and self._cv.wait(max(0.0, end - time.monotonic())):
                pass
            entry = self._emcy.get(nid)
        code = entry.code if entry is not None else self.sdo_read(nid, 0x603F)
        raise ProtocolError(f"drive in FAULT (statusword 0x{sw:04X})", code=code, text=emcy_text(code),
                            device=self.node_name(nid))

    def _await(self, nid: int, done, what: str, timeout: float, faults: bool = True) -> int:
        end = time.monotonic() + timeout
        while True:
            sw = self.statusword(nid)
            if faults and sw & 0x0008:
                self._raise_fault(nid, sw)
            if done(sw):
                return sw
            if time.monotonic() > end:
                raise DeviceTimeout(f"{what} not reached within {timeout:.3g} s (state {state_name(sw)}, "
                                    f"statusword 0x{sw:04X})", device=self.node_name(nid))
            self.check_health()
            time.sleep(_SDO_POLL_S)

    def _state_is(self, name):
        return lambda sw: state_name(sw) == name

    def enable(self, timeout: float | None = None) -> None:
        """Shutdown, switch on, enable operation on every drive (a faulted drive raises)."""
        timeout = self.timeout if timeout is None else float(timeout)
        self.check_health()
        for nid in self.nodes:
            sw = self.statusword(nid)
            if sw & 0x0008:
                self._raise_fault(nid, sw)
            if state_name(sw) == "OPERATION ENABLED":
                continue
            for cw, target in ((0x06, "READY TO SWITCH ON"), (0x07, "SWITCHED ON"), (0x0F, "OPERATION ENABLED")):
                self.sdo_write(nid, 0x6040, cw)
                self._await(nid, self._state_is(target), target, timeout)

    def disable(self) -> None:
        """Controlword shutdown (0x06): drives leave OPERATION ENABLED."""
        for nid in self.nodes:
            self.sdo_write(nid, 0x6040, 0x06)

    def fault_reset(self, timeout: float | None = None, enable: bool = True) -> None:
        """Clear faults (rising edge of controlword bit 7, 0x80) and, by default, enable again."""
        timeout = self.timeout if timeout is None else float(timeout)
        self.check_health()
        for nid in self.nodes:
            if self.statusword(nid) & 0x0008:
                self.sdo_write(nid, 0x6040, 0x00)
                self.sdo_write(nid, 0x6040, 0x80)
                self._await(nid, self._state_is("SWITCH ON DISABLED"), "SWITCH ON DISABLED", timeout, faults=False)
            with self._cv:
                self._emcy[nid] = None
        if enable:
            self.enable(timeout)

    def move_to(self, qm_targets: Sequence[float], timeout: float | None = None) -> None:
        """Start a move of every actuator to ``qm_targets`` (actuator units) with the
        set-point handshake: target 0x607A, controlword bit 4 up, statusword bit 12
        acknowledge, bit 4 down. Returns once all drives acknowledged."""
        targets = [float(q) for q in qm_targets]
        if len(targets) != len(self.nodes) or not all(math.isfinite(q) for q in targets):
            raise ValueError(f"qm_targets: need {len(self.nodes)} finite values, got {list(qm_targets)!r}")
        timeout = self.timeout if timeout is None else float(timeout)
        self.check_health()
        for i, nid in enumerate(self.nodes):
            sw = self.statusword(nid)
            if sw & 0x0008:
                self._raise_fault(nid, sw)
            if state_name(sw) != "OPERATION ENABLED":
                raise DeviceError(f"cannot move in state {state_name(sw)}; call enable()", device=self.node_name(nid))
            self.sdo_write(nid, 0x607A, round(targets[i] * self.resolution[i]))
        for nid in self.nodes:      # new set-point + change set immediately + enable operation
            self.sdo_write(nid, 0x6040, 0x3F)
        for nid in self.nodes:
            self._await(nid, lambda sw: sw & 0x1000, "set-point acknowledge", timeout)
            self.sdo_write(nid, 0x6040, 0x2F)

    def wait_target_reached(self, timeout: float = 30.0) -> Sample:
        """Wait until every drive reports target reached (statusword bit 10); returns a
        fresh sample. DeviceTimeout names the first drive still moving."""
        end = time.monotonic() + float(timeout)
        for nid in self.nodes:
            self._await(nid, lambda sw: sw & 0x0400, "target", max(0.0, end - time.monotonic()))
        return self.read()


class CanopenEncoders(CanopenNodes):
    """Read-only CiA 406 encoders: position value 0x6004 (UNSIGNED32) in TPDO1
    (0x1A00:01 = 0x60040020) on SYNC, preset 0x6003. For robots whose own
    controller moves the arm. ``signed=True`` reads counts at or above 2**31 as
    negative (a multi-turn count that wrapped below zero)."""

    profile = 0x0196
    position_object = 0x6004
    tpdo_objects = ((0x6004, 32),)

    def __init__(self, nodes, resolution, *, signed: bool = True, **options):
        super().__init__(nodes, resolution, **options)
        self.signed = bool(signed)

    def _decode(self, raw: int) -> int:
        return raw - (1 << 32) if self.signed and raw >= 1 << 31 else raw

    def preset(self, qm_values: Sequence[float]) -> None:
        """Set each encoder's present position to ``qm_values`` (actuator units) through 0x6003."""
        values = [float(q) for q in qm_values]
        if len(values) != len(self.nodes) or not all(math.isfinite(q) for q in values):
            raise ValueError(f"qm_values: need {len(self.nodes)} finite values, got {list(qm_values)!r}")
        for i, nid in enumerate(self.nodes):
            self.sdo_write(nid, 0x6003, round(values[i] * self.resolution[i]) & 0xFFFFFFFF)


def canopen_device(cfg, **options) -> CanopenNodes:
    """The device a :class:`drivers.config.CanopenConfig` describes: drives (``mode="cia402"``)
    or encoders (``"cia406"``); not opened."""
    return (CanopenEncoders if cfg.mode == "cia406" else CanopenActuators).from_config(cfg, **options)
