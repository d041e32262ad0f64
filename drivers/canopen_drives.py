"""CANopen actuators (CiA 402 drives) and encoders (CiA 406) over python-can + canopen.

Every node is a canopen ``RemoteNode`` on one ``canopen.Network``; positions
are sampled together by SYNC + TPDO1, heartbeats are watched (see
:mod:`drivers.canopen_nodes`, the common part). A drive fault raises
:class:`ProtocolError` carrying the EMCY code and its text.

Units: positions in actuator units ``Qm`` = increments / ``resolution``
(increments per actuator unit, one for all nodes or one per node); velocities
in units/s, accelerations in units/s^2, times in seconds.

Layout: this module holds the drives (:class:`CanopenActuators`) and
:func:`canopen_device`; the common node handling is in
:mod:`drivers.canopen_nodes` (its bus in :mod:`drivers.canopen_bus`, its SDO and
SYNC + TPDO exchanges in :mod:`drivers.canopen_exchanges`), the encoders in
:mod:`drivers.canopen_encoders`, the object dictionary and code tables in
:mod:`drivers.canopen_od`. Their public names are importable from here as well.
"""
from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Iterator, Sequence

from calibration.errors import ConfigError
from drivers.base import Sample
from drivers.canopen_encoders import CanopenEncoders
from drivers.canopen_nodes import CanopenNodes
from drivers.canopen_od import EMCY_TEXT, NMT_OPERATIONAL, emcy_text, standard_od, state_name
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

__all__ = ["EMCY_TEXT", "NMT_OPERATIONAL", "CanopenActuators", "CanopenEncoders", "CanopenNodes",
           "canopen_device", "emcy_text", "standard_od", "state_name"]

_SDO_POLL_S = 0.005
log = logging.getLogger("drivers.canopen")


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

    @classmethod
    def _config_options(cls, cfg) -> dict:
        return {"velocity": tuple(cfg.profile_velocity) or None,
                "acceleration": tuple(cfg.profile_acceleration) or None}

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
        text = emcy_text(code)
        vendor = bytes(getattr(entry, "data", b"") or b"").rstrip(b"\0")
        if vendor and all(32 <= c < 127 for c in vendor):
            text += f" (drive says {vendor.decode('ascii')!r})"   # manufacturer bytes, printable
        raise ProtocolError(f"drive in FAULT (statusword 0x{sw:04X})", code=code, text=text,
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
            if sw & 0x1000:   # a handshake left half done (a master died between its writes):
                # bit 4 is still high, so a new set-point would make no rising edge
                self.sdo_write(nid, 0x6040, 0x2F)
                self._await(nid, lambda w: not w & 0x1000, "set-point acknowledge cleared", timeout)
            self.sdo_write(nid, 0x607A, round(targets[i] * self.resolution[i]))
        for nid in self.nodes:      # new set-point + change set immediately + enable operation
            self.sdo_write(nid, 0x6040, 0x3F)
        for nid in self.nodes:
            self._await(nid, lambda sw: sw & 0x1000, "set-point acknowledge", timeout)
            self.sdo_write(nid, 0x6040, 0x2F)

    @contextlib.contextmanager
    def slower(self, factor: float) -> Iterator[None]:
        """Moves started inside run at ``factor`` (0 < factor <= 1) of every drive's
        profile velocity and ``factor**2`` of its acceleration (the same profile,
        stretched in time by ``1 / factor``); each drive's own values (0x6081, 0x6083, read
        first) are written back after. Where a drive cannot be reached to write them
        back, that is logged, not raised over the error that left the block: the profile
        is written again when the drives are opened (a reconnection)."""
        if not 0.0 < factor <= 1.0:
            raise ValueError(f"factor must be in (0, 1], not {factor!r}")
        saved = {nid: (self.sdo_read(nid, 0x6081), self.sdo_read(nid, 0x6083))
                 for nid in self.nodes}
        for nid, (v, a) in saved.items():
            if not (v > 0 and a > 0):
                raise DeviceError(f"profile velocity 0x6081 = {v}, acceleration 0x6083 = {a}: "
                                  "no profile to slow down; give [canopen] profile_velocity "
                                  "and profile_acceleration in the station config",
                                  device=self.node_name(nid))
        try:
            for nid, (v, a) in saved.items():
                self.sdo_write(nid, 0x6081, max(1, round(v * factor)))
                self.sdo_write(nid, 0x6083, max(1, round(a * factor * factor)))
            yield
        finally:
            for nid, (v, a) in saved.items():
                try:
                    self.sdo_write(nid, 0x6081, v)
                    self.sdo_write(nid, 0x6083, a)
                except DeviceError as e:
                    log.warning("%s: profile not restored: %s", self.node_name(nid), e)

    def wait_target_reached(self, timeout: float = 30.0) -> Sample:
        """Wait until every drive reports target reached (statusword bit 10); returns a
        fresh sample. DeviceTimeout names the first drive still moving."""
        end = time.monotonic() + float(timeout)
        for nid in self.nodes:
            self._await(nid, lambda sw: sw & 0x0400, "target", max(0.0, end - time.monotonic()))
        return self.read(max(self.timeout, end - time.monotonic()))


def canopen_device(cfg, **options) -> CanopenNodes:
    """The device a :class:`drivers.config.CanopenConfig` describes: drives (``mode="cia402"``)
    or encoders (``"cia406"``); not opened."""
    return (CanopenEncoders if cfg.mode == "cia406" else CanopenActuators).from_config(cfg, **options)
