"""The common part of the station's CANopen devices (python-can + canopen): the nodes,
their configuration and their health (:class:`CanopenNodes`).

Every node is a canopen ``RemoteNode`` on one ``canopen.Network``; SDO, PDO and
NMT are the library's. At open, each node's device type is checked against the
profile, its heartbeat producer time (0x1017) set and its TPDO1 mapped (transmission
type 1: sent on every SYNC), then NMT starts it and the master awaits its OPERATIONAL
heartbeat. Heartbeats are watched: a silent node is
``"canopen node 3: heartbeat lost ..."``; EMCYs are kept per node for the drives.

Layout: the CAN bus under the network (opening, closing, the receive thread's end) is
:mod:`drivers.canopen_bus`; the SDO transfers and the SYNC + TPDO sampling
(``sync_wait``, :class:`~drivers.canopen_exchanges.TpdoLost`) are
:mod:`drivers.canopen_exchanges`. The profiles are
:class:`drivers.canopen_drives.CanopenActuators` (CiA 402) and
:class:`drivers.canopen_encoders.CanopenEncoders` (CiA 406).

Units: positions in actuator units ``Qm`` = increments / ``resolution``
(increments per actuator unit, one for all nodes or one per node); times in
seconds.
"""
from __future__ import annotations

import functools
import math
import threading
import time
from collections.abc import Sequence

import canopen

from calibration.errors import ConfigError
from drivers.base import Device
from drivers.canopen_bus import BusLoss, bus_error_text, close_network, open_network
from drivers.canopen_exchanges import CanopenExchanges
from drivers.canopen_od import NMT_OPERATIONAL, standard_od
from drivers.errors import DeviceError, DeviceTimeout


class CanopenNodes(CanopenExchanges, Device):
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
        network = open_network(self.bus_config, self.timeout, self.name)
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
            close_network(network)

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
