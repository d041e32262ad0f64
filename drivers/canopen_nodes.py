"""The common part of the station's CANopen devices (python-can + canopen).

Every node is a canopen ``RemoteNode`` on one ``canopen.Network``; SDO, PDO and
NMT are the library's. Positions are sampled together: the master sends one
SYNC and waits for every node's TPDO1 (transmission type 1, mapping statusword
0x6041 + position actual value 0x6064, or position value 0x6004 for an
encoder). A TPDO is taken for the one SYNC the master awaits: a node whose TPDO
has not come after ``sync_wait`` is asked over SDO, and its TPDO comes before
that answer or is lost (then the SYNC is repeated within the read timeout); a
node whose TPDO does not come in time gives :class:`DeviceTimeout` naming it,
never an older value (:class:`CanopenNodes`, ``sync_wait``). Heartbeats
(producer time 0x1017, set by the master) are watched: a silent node is
``"canopen node 3: heartbeat lost ..."``.

Units: positions in actuator units ``Qm`` = increments / ``resolution``
(increments per actuator unit, one for all nodes or one per node); times in
seconds. The profiles are :class:`drivers.canopen_drives.CanopenActuators`
(CiA 402) and :class:`drivers.canopen_encoders.CanopenEncoders` (CiA 406).
"""
from __future__ import annotations

import contextlib
import functools
import math
import socket
import threading
import time
from collections.abc import Sequence

import can
import canopen
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from calibration.errors import ConfigError
from drivers.base import Device, Sample, log
from drivers.canopen_od import NMT_OPERATIONAL, standard_od
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

#: how canopen (2.3-2.4) begins its errors for an answer to another SDO request than
#: the one waiting: an upload's answer about another object, a download's answer to
#: an upload, an upload's answer (command 0x4x) to a download (tests/drivers/
#: test_canopen.py provokes the first and the last)
FOREIGN_TO_UPLOAD = ("Node returned a value for", "Unexpected response 0x60")
FOREIGN_TO_DOWNLOAD = ("Unexpected response 0x4",)


#: seconds a CAN bus may take to come up (the socketcand greeting, python-can's connect)
CONNECT_TIMEOUT_S = 3.0


class TpdoLost(DeviceTimeout):
    """A SYNC's TPDO is lost on the bus: the node answered an SDO request sent after the
    SYNC, and its TPDO, which it would have sent first, had not come."""


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
    sync_wait:         seconds a SYNC's TPDOs are awaited before the nodes still missing
                       are asked over SDO (the barrier): a node's TPDO of a SYNC is on the
                       bus before its answer to an SDO request sent after that SYNC (it
                       is sent first, and at a higher priority), so a TPDO that comes in
                       before that answer is taken for the SYNC, however late (a slow bus,
                       a busy machine), and one that has not come is lost. A SYNC whose
                       TPDOs are lost is repeated as long as the reading's timeout lasts;
                       repeats count in ``resyncs``. A TPDO never answers a later SYNC: a
                       node that has a SYNC's TPDO outstanding (a reading given up) is
                       asked over SDO before the next SYNC goes out, and a TPDO outside
                       its SYNC's window counts in ``unsolicited_tpdos``.
    """

    profile = 0x0192                      # low word of 0x1000
    position_object = 0x6064
    tpdo_objects: tuple[tuple[int, int], ...] = ((0x6041, 16), (0x6064, 32))

    def __init__(self, nodes: Sequence[int], resolution: float | Sequence[float], *,
                 interface: str = "socketcan", channel: str = "can0", bus_options: dict | None = None,
                 timeout: float = 1.0, heartbeat_ms: int = 100, heartbeat_timeout: float | None = None,
                 read_via: str = "tpdo", name: str = "canopen", sync_wait: float = 0.05):
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
        self._sync_t = 0.0
        self._pending: set[int] = set()
        self._fresh: dict[int, tuple] = {}
        self._outstanding: set[int] = set()   # nodes that may still send a given-up SYNC's TPDO
        self.unsolicited_tpdos = 0        # TPDOs that came outside a SYNC window (late or extra)
        self.sync_wait = float(sync_wait)
        self.resyncs = 0                  # SYNCs repeated because TPDOs were lost

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
        kw.update(cls._config_options(cfg))
        return cls(cfg.nodes, cfg.increments_per_unit, **dict(kw, **options))

    @classmethod
    def _config_options(cls, cfg) -> dict:
        """Profile-specific constructor arguments taken from a CanopenConfig (none here)."""
        return {}

    def node_name(self, nid: int) -> str:
        return f"canopen node {nid}"

    # -- lifecycle ------------------------------------------------------------
    def _open_internal(self) -> None:
        self._last_hb.clear(), self._hb_state.clear(), self._emcy.clear()
        self._outstanding = set()
        network = canopen.Network()
        try:
            self._server_answers()
            self._connect(network)
        except DeviceError:
            raise
        except (can.CanError, OSError, ValueError, ImportError) as e:
            raise DeviceError(f"cannot open the CAN bus {_bus_text(self.bus_config)}: "
                              f"{bus_error_text(e)}",
                              device=self.name) from e
        self.network = network
        network.notifier.add_listener(BusLoss(network))
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

    def _bus_text(self) -> str:
        cfg = self.bus_config
        where = f" at {cfg['host']}:{cfg['port']}" if cfg.get("host") else ""
        return f"CAN bus {cfg.get('interface')} {cfg.get('channel')}{where}"

    def _server_answers(self) -> None:
        """A socketcand server that refuses the connection (not running, the cable or
        the simulator gone) is an OSError at once: python-can's socketcand interface
        would retry a refused connection for 10 s in a busy loop. One that accepts the
        connection and says nothing (a hung server, another service on that port) is a
        :class:`DeviceTimeout` within :data:`CONNECT_TIMEOUT_S`: python-can would wait
        for its greeting ``< hi >`` for ever."""
        cfg = self.bus_config
        if cfg.get("interface") != "socketcand" or not (cfg.get("host") and cfg.get("port")):
            return
        limit = max(CONNECT_TIMEOUT_S, self.timeout)
        with socket.create_connection((cfg["host"], int(cfg["port"])), timeout=limit) as s:
            s.settimeout(limit)
            got = b""
            try:
                while b">" not in got and len(got) < 256:
                    chunk = s.recv(256)
                    if not chunk:
                        raise DeviceError(f"{self._bus_text()}: the server closed the connection "
                                          "without the socketcand greeting", device=self.name)
                    got += chunk
            except TimeoutError:
                raise DeviceTimeout(f"{self._bus_text()}: the server accepted the connection but "
                                    f"sent no socketcand greeting within {limit:g} s (a hung "
                                    "server, or not socketcand on that port)",
                                    device=self.name) from None
            if not got.strip().startswith(b"< hi >"):
                raise DeviceError(f"{self._bus_text()}: not a socketcand server (it said "
                                  f"{got[:40]!r})", device=self.name)

    def _connect(self, network) -> None:
        """``network.connect`` bounded by :data:`CONNECT_TIMEOUT_S` (python-can's
        connect has no timeout of its own): a bus that does not come up in time is a
        :class:`DeviceTimeout` naming it; the connect left behind is shut down when
        it ends."""
        done, box = threading.Event(), {}

        def connect():
            try:
                network.connect(**self.bus_config)
            except BaseException as e:          # handed to the caller
                box["error"] = e
            finally:
                done.set()
                if box.get("abandoned"):
                    with contextlib.suppress(Exception):
                        network.disconnect()

        limit = max(CONNECT_TIMEOUT_S, self.timeout)
        threading.Thread(target=connect, name=f"{self.name} connect", daemon=True).start()
        if not done.wait(limit):
            box["abandoned"] = True
            raise DeviceTimeout(f"{self._bus_text()}: no connection within {limit:g} s",
                                device=self.name)
        if "error" in box:
            raise box["error"]

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
            if network.notifier is not None:
                network.notifier.exception = None   # said already; canopen would log it again
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
        notifier = self.network.notifier
        lost = notifier.exception if notifier is not None else None
        if lost is not None:
            raise DeviceError(f"CAN receive thread stopped: {bus_error_text(lost)}",
                              device=self.name) from lost
        for nid in self.nodes:
            self._check_heartbeat(nid)

    def _check_heartbeat(self, nid: int) -> None:
        """Raise if node ``nid``'s heartbeat is overdue or says it left OPERATIONAL."""
        with self._cv:
            now = time.monotonic()
            age = now - self._last_hb.get(nid, now)
            if age > self.heartbeat_timeout:
                raise DeviceTimeout(f"heartbeat lost (none for {age:.2f} s, limit {self.heartbeat_timeout:.2f} s)",
                                    device=self.node_name(nid))
            state = self._hb_state.get(nid)
            if state is not None and state != NMT_OPERATIONAL:
                label = canopen.nmt.NMT_STATES.get(state, state)
                raise DeviceError(f"left OPERATIONAL (heartbeat says {label})", device=self.node_name(nid))

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
            raise DeviceError(f"CAN bus error while {what}: {bus_error_text(e)}",
                              device=self.node_name(nid)) from e

    # -- reading --------------------------------------------------------------------
    def sdo_read(self, nid: int, index: int, subindex: int = 0):
        """One SDO upload (decoded with the standard object dictionary); asked once
        more where the answer was another request's (:meth:`_own_answer`)."""
        with self._io(nid, f"reading 0x{index:04X}:{subindex:02X}"):
            obj = self.remote[nid].sdo[index]
            var = obj[subindex] if subindex else obj
            return self._own_answer(nid, lambda: var.raw, FOREIGN_TO_UPLOAD)

    def sdo_write(self, nid: int, index: int, value, subindex: int = 0) -> None:
        """One SDO download; asked once more where the answer was another request's
        (:meth:`_own_answer`: the same value again, which the node took already)."""
        with self._io(nid, f"writing 0x{index:04X}:{subindex:02X} = {value}"):
            obj = self.remote[nid].sdo[index]
            var = obj[subindex] if subindex else obj

            def write():
                var.raw = value
            self._own_answer(nid, write, FOREIGN_TO_DOWNLOAD)

    def _own_answer(self, nid: int, exchange, foreign: tuple[str, ...]):
        """``exchange()`` (one SDO transfer with node ``nid``), asked once more where
        the answer it got was another request's (canopen's error begins with one of
        ``foreign``): the late answer to a request given up on (a timeout; the TPDO
        barrier's time running out) that came in after this request was sent. That
        answer is dropped; this request's own answer, where it comes in meanwhile, is
        the one the second transfer then takes (the same object: a moment older for
        an upload, the same value taken for a download)."""
        try:
            return exchange()
        except SdoCommunicationError as e:
            if not str(e).startswith(foreign):
                raise
            log.info("%s: %s; the transfer asked again", self.node_name(nid), e)
            return exchange()

    def _to_units(self, i: int, increments: int) -> float:
        return increments / self.resolution[i]

    def sync_sample(self, timeout: float | None = None, window: float | None = None) -> dict[int, tuple]:
        """Send one SYNC; return each node's TPDO values of that SYNC (``{nid: (values...)}``).

        The TPDOs are awaited ``window`` s (default: all of ``timeout``); a node still
        missing then is asked over SDO within the rest of ``timeout`` (the barrier,
        :meth:`_barrier`), and its TPDO is taken if it comes in before the answer.
        :class:`TpdoLost` where TPDOs are proven lost (the nodes answered), DeviceTimeout
        where a node did not answer in time or its heartbeat is lost."""
        timeout = self.timeout if timeout is None else float(timeout)
        return self._sync_once(time.monotonic() + timeout, window, timeout)

    def _sync_once(self, end: float, window: float | None, timeout: float) -> dict[int, tuple]:
        """:meth:`sync_sample` until ``end`` (``time.monotonic()``); ``timeout`` names it
        in errors."""
        self.check_health()
        for nid in sorted(self._outstanding):  # a given-up SYNC's TPDO is in before the answer
            self._check_heartbeat(nid)
            if not self._barrier(nid, end):
                raise DeviceTimeout(f"no SDO answer within {timeout:.3g} s (a TPDO of an earlier "
                                    "SYNC may still come); stale sample refused",
                                    device=self.node_name(nid))
        with self._cv:
            self._sync_no += 1
            self._pending, self._fresh = set(self.nodes), {}
            self._outstanding = set(self.nodes)
            self._sync_t = time.monotonic()   # the drives latch their positions at this SYNC
        try:
            self.network.sync.transmit()
        except (can.CanError, OSError) as e:
            with self._cv:
                self._pending = set()
            raise DeviceError(f"cannot send SYNC: {bus_error_text(e)}", device=self.name) from e
        close = end if window is None else min(end, self._sync_t + max(0.0, float(window)))
        answered: set[int] = set()
        in_time = True
        try:
            with self._cv:
                while self._pending and self._cv.wait(max(0.0, close - time.monotonic())):
                    pass
                missing = sorted(self._pending)
            for nid in missing:
                with self._cv:
                    if nid not in self._pending:      # came in during an earlier node's barrier
                        continue
                self._check_heartbeat(nid)            # a dead node fails at once
                in_time = self._barrier(nid, end)
                if not in_time:
                    break
                answered.add(nid)
        finally:
            with self._cv:
                missing, fresh = sorted(self._pending), self._fresh
                self._pending = set()
                self._outstanding = set(missing) - answered
        if missing:
            also = f" (also nodes {missing[1:]})" if len(missing) > 1 else ""
            if not in_time:
                raise DeviceTimeout(f"no TPDO for SYNC #{self._sync_no} within {timeout:.3g} s; "
                                    f"stale sample refused{also}", device=self.node_name(missing[0]))
            raise TpdoLost(f"TPDO of SYNC #{self._sync_no} lost (the node answered an SDO request "
                           f"sent after it); stale sample refused{also}", device=self.node_name(missing[0]))
        return fresh

    def _barrier(self, nid: int, end: float) -> bool:
        """One SDO exchange with node ``nid`` (device type 0x1000) before ``end``: every
        frame the node sent before its answer (a TPDO of a SYNC sent before the request)
        has come in when it returns True; False where time ran out first. A silent node
        is found by its heartbeat after ``heartbeat_timeout`` (DeviceTimeout)."""
        sdo = self.remote[nid].sdo
        try:
            while True:
                left = end - time.monotonic()
                if left <= 0:
                    return False
                sdo.RESPONSE_TIMEOUT = min(left, self.heartbeat_timeout)
                try:
                    sdo.upload(0x1000, 0)
                    return True
                except SdoAbortedError:
                    return True                   # an answer all the same
                except SdoCommunicationError:
                    self._check_heartbeat(nid)    # dead: heartbeat lost; else ask again
                except (can.CanError, OSError) as e:
                    raise DeviceError(f"CAN bus error while asking after a TPDO: {bus_error_text(e)}",
                                      device=self.node_name(nid)) from e
        finally:
            sdo.RESPONSE_TIMEOUT = self.timeout

    def _read_internal(self, timeout: float) -> Sample:
        if self.read_via == "sdo":
            return self.read_sdo(timeout)
        end = time.monotonic() + timeout
        syncs = 0
        while True:
            syncs += 1
            try:   # a lost TPDO costs one more SYNC, not the reading, while time remains; a
                # dead node still fails at once (its heartbeat is checked in _sync_once)
                fresh = self._sync_once(end, self.sync_wait, timeout)
                break
            except TpdoLost as e:
                if time.monotonic() >= end:
                    raise TpdoLost(f"no SYNC answered by every node within {timeout:.3g} s ({syncs} "
                                   f"SYNCs, TPDOs lost on the bus); stale sample refused",
                                   device=e.device) from e
                self.resyncs += 1
                log.info("%s: %s; SYNC again", self.name, e)
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
        since = time.monotonic()
        for nid in self.nodes:
            self.remote[nid].sdo.RESPONSE_TIMEOUT = self.timeout if timeout is None else float(timeout)
            try:
                raw[nid] = self.sdo_read(nid, self.position_object)
            finally:
                self.remote[nid].sdo.RESPONSE_TIMEOUT = self.timeout
        values = {ch: self._to_units(i, self._decode(raw[n])) for i, (ch, n) in enumerate(zip(self.channels, self.nodes))}
        self._sync_no += 1
        return Sample(time.monotonic(), values, seq=self._sync_no,
                      info={"source": "sdo", "increments": raw, "since": since})

    def _decode(self, raw: int) -> int:
        return raw

    def _info(self, fresh: dict[int, tuple], source: str) -> dict:
        pos = [o for o, _ in self.tpdo_objects].index(self.position_object)
        # "since": the SYNC's time; the values were latched between it and the sample's t
        return {"source": source, "sync": self._sync_no, "since": self._sync_t,
                "increments": {n: v[pos] for n, v in fresh.items()}}


class BusLoss(can.Listener):
    """Hears the end of python-can's receive thread: a bus that fails under it (the
    socketcand server or its cable gone, a connection reset) is handed to ``on_error``.
    Handled here, the thread ends without an unhandled exception (whose traceback would
    land on the operator's terminal); its ``notifier.exception`` stays, and
    :meth:`CanopenNodes.check_health` names it at the device's next call."""

    def __init__(self, network):
        self.network = network

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        notifier = self.network.notifier
        if notifier is not None:
            notifier.stop(timeout=-1)     # ends the receive loop; never joins this thread


def bus_error_text(e: BaseException) -> str:
    """A CAN error in one line: python-can folds the failing call's traceback into the
    message of the error its receive thread ends with; the root cause is said instead
    (``connection reset by peer``)."""
    root = e
    while root.__cause__ is not None or root.__context__ is not None:
        root = root.__cause__ or root.__context__
    text = str(root).split("Traceback (most recent call last)")[0].strip()
    if isinstance(root, OSError) and root.strerror:
        text = root.strerror
    first = text.splitlines()[0].strip() if text else type(root).__name__
    return first[:1].lower() + first[1:]


def _bus_text(bus: dict) -> str:
    """A CAN bus's settings for people: ``socketcand can0 at 127.0.0.1:29536``."""
    b = dict(bus)
    where = f"{b.pop('host')}:{b.pop('port')}" if "host" in b and "port" in b else ""
    head = " ".join(str(b.pop(k)) for k in ("interface", "channel") if b.get(k) is not None)
    rest = ", ".join(f"{k} {v}" for k, v in b.items() if v is not None and not isinstance(v, dict))
    return " ".join(x for x in (head, f"at {where}" if where else "", f"({rest})" if rest else "")
                    if x) or "(no settings)"
