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
[increments/unit]); 0x6081 in increments/s and 0x6083 in increments/s^2. The axis
position is the motor's: a truth's ``repeatability`` (backlash, a random positioning
error per move) is between it and the link (:mod:`drivers.sim.axis`), unseen here.

Layout: the node classes are in :mod:`drivers.sim.sim_nodes`, the faulty,
delaying network in :mod:`drivers.sim.sim_network`; this module starts them
(:class:`SimulatedDrives`, :func:`start_canopen_sim`, :func:`run_sim_process`)
and re-exports their names.
"""
from __future__ import annotations

import functools

from drivers.sim.axis import SimAxis
from drivers.sim.faults import FaultPlan
from drivers.sim.sim_network import SimNetwork
from drivers.sim.sim_nodes import EDS_PATH, SW, SimDrive402, SimEncoder406, SimNode, cia406_od

__all__ = ["EDS_PATH", "SW", "CanopenSim", "SimDrive402", "SimEncoder406", "SimNetwork", "SimNode",
           "SimulatedDrives", "cia406_od", "run_sim_process", "start_canopen_sim"]


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
    supervise:  optional ``supervise() -> (i, data) | None``, asked before each statusword
                read: the robot hit a physical limit at axis ``i``, whose drive goes to
                FAULT with EMCY 0x8612 (reference limit) and manufacturer bytes ``data``.
    """

    def __init__(self, bus: dict, nodes, axes, resolution, plan: FaultPlan | None = None,
                 profile: str = "cia402", increments=None, supervise=None):
        self.increments = increments
        self.supervise = supervise
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
            self.nodes[nid] = kind(network, nid, axis, res, self.plan, increments=inc,
                                   check=self._check_limits if self.supervise else None)
        network.subscribe(0x80, self._on_sync)
        self.network = network
        for node in self.nodes.values():
            node.boot()
        return self

    def _check_limits(self) -> None:
        hit = self.supervise()
        if hit is not None:
            i, data = hit
            node = self.nodes[self.node_ids[i]]
            if node.state != "FAULT":
                node.fault(0x8612, register=0x21, data=data)

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
                      increments=None, supervise=None) -> CanopenSim:
    """Start a socketcand hub on ``host:port`` (0: ephemeral) and the simulated nodes
    on it, in this process (threads). Arguments as :class:`SimulatedDrives`.
    Returns a :class:`CanopenSim` (``.endpoint``, ``.drives``, ``.hub``, ``.stop()``)."""
    from drivers.sim.socketcand_hub import SocketcandHub
    hub = SocketcandHub(host, port, channel).start()
    try:
        drives = SimulatedDrives(hub.endpoint, nodes, axes, resolution, plan, profile, increments,
                                 supervise).start()
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
