"""The exchanges of the station's CANopen devices with their nodes: SDO transfers and the
SYNC + TPDO sampling (:class:`CanopenExchanges`, a part of
:class:`drivers.canopen_nodes.CanopenNodes`).

Positions are sampled together: the master sends one SYNC and waits for every node's
TPDO1 (transmission type 1, mapping statusword 0x6041 + position actual value 0x6064,
or position value 0x6004 for an encoder). A TPDO is taken for the one SYNC the master
awaits: a node whose TPDO has not come after ``sync_wait`` is asked over SDO, and its
TPDO comes before that answer or is lost (then the SYNC is repeated within the read
timeout); a node whose TPDO does not come in time gives :class:`DeviceTimeout` naming
it, never an older value. ``read_via="sdo"`` reads by one SDO upload per node instead.
An SDO answer that was another request's (a late answer to one given up on) is dropped
and the transfer asked once more. Every canopen/python-can error of an exchange becomes
a station error naming the node (:meth:`CanopenExchanges._io`).

Units: positions in actuator units ``Qm`` = increments / ``resolution``; times in seconds.
"""
from __future__ import annotations

import contextlib
import time

import can
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from drivers.base import Sample, log
from drivers.canopen_bus import bus_error_text
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError

#: how canopen (2.3-2.4) begins its errors for an answer to another SDO request than
#: the one waiting: an upload's answer about another object, a download's answer to
#: an upload, an upload's answer (command 0x4x) to a download (tests/drivers/
#: test_canopen.py provokes the first and the last)
FOREIGN_TO_UPLOAD = ("Node returned a value for", "Unexpected response 0x60")
FOREIGN_TO_DOWNLOAD = ("Unexpected response 0x4",)


class TpdoLost(DeviceTimeout):
    """A SYNC's TPDO is lost on the bus: the node answered an SDO request sent after the
    SYNC, and its TPDO, which it would have sent first, had not come."""


class CanopenExchanges:
    """SDO transfers and SYNC + TPDO sampling of :class:`~drivers.canopen_nodes.CanopenNodes`
    (whose constructor sets the state used here: ``nodes``, ``channels``, ``resolution``,
    ``remote``, ``network``, ``timeout``, ``heartbeat_timeout``, ``read_via``,
    ``sync_wait``, the condition ``_cv`` and the SYNC bookkeeping; its health checks
    :meth:`check_health` and :meth:`_check_heartbeat`). Subclasses set the profile
    (``position_object``, ``tpdo_objects``, :meth:`_decode`, :meth:`_info`)."""

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

    # -- SDO ------------------------------------------------------------------------
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

    # -- SYNC + TPDO (the receive thread calls _on_tpdo) ------------------------------
    def _on_tpdo(self, nid: int, pdo_map) -> None:
        values = tuple(var.raw for var in pdo_map.map)
        with self._cv:
            if nid in self._pending:
                self._fresh[nid] = values
                self._pending.discard(nid)
                self._cv.notify_all()
            else:
                self.unsolicited_tpdos += 1

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

    # -- reading --------------------------------------------------------------------
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
