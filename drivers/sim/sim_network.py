"""The simulated nodes' side of the CAN bus: a canopen ``Network`` with faults and delay.

Every frame a simulated node sends passes the :class:`~drivers.sim.faults.FaultPlan`
on the wire: ``silent_nodes`` send nothing and do not hear their SDO requests;
``drop_prob`` and ``corrupt_prob`` drop TPDOs (a corrupted CAN frame never
passes the CRC); ``late_s`` delays every frame. Periodic frames (heartbeats) are
sent by the same transmit thread, so the faults apply to them too.
"""
from __future__ import annotations

import collections
import logging
import threading
import time

import can
import canopen

from drivers.sim.faults import FaultPlan

log = logging.getLogger("drivers.sim.canopen")


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
