"""Simulated Modbus draw-wire sensor: a pymodbus 3.16 server (house style 2).

Register map as :mod:`drivers.drawwire`; values are computed at read time:
``count = round((length_m() - offset_m) / metres_per_count)`` (UINT32, wraps),
``turns = count // counts_per_turn``. Writing 1 to 0x0008 sets ``offset_m`` to
the current length (count 0 here) and then calls the ``zero`` hook. Other
function codes than 03/06 answer "illegal function"; unmapped addresses
"illegal data address".

Transports: Modbus TCP on ``host:port`` (127.0.0.1, ephemeral by default) and
Modbus RTU over a pseudo-terminal (:attr:`rtu_port` is the path a client opens;
the server sits on a second pty, the two masters bridged by a thread).
Faults from :class:`FaultPlan`: ``modbus_exception``, ``drawwire_down`` (TCP
listener and connections closed, RTU bytes dropped), ``late_s``,
``drawwire_unanswered`` (after ``drawwire_answer_first`` answered requests, that
many requests get no answer at all: the client times out and, over TCP, closes
the connection; over RTU nothing is ever sent for them either).

Child process: ``python -m drivers.sim.drawwire_sim`` (see :func:`main`).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import select
import sys
import threading
import tty
from collections.abc import Callable

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from drivers.drawwire import REG_COUNT, REG_TURNS, REG_ZERO, split_words
from drivers.sim.faults import FaultPlan
from drivers.sim.inclinometer_sim import SimProcess  # noqa: F401  (re-exported for tests)


class SimDrawWire:
    """A draw-wire sensor served over Modbus TCP and RTU from a background asyncio loop.

    length_m:         callable -> cable length (m), called at every read.
    zero:             hook called after the device zeroed (write 1 to 0x0008).
    metres_per_count: wire travel per count (m); offset_m: length (m) at count 0.
    word_order:       ``"big"`` (high word first) or ``"little"``; may be changed live.
    port:             TCP port (0: ephemeral; the bound one is in :attr:`port` after start).
    rtu:              also serve RTU over a pty (:attr:`rtu_port`).
    """

    def __init__(self, length_m: Callable[[], float], *, zero: Callable[[], None] | None = None,
                 metres_per_count: float = 1e-4, offset_m: float = 0.0,
                 counts_per_turn: int = 2000, word_order: str = "big", device_id: int = 1,
                 host: str = "127.0.0.1", port: int = 0, rtu: bool = True,
                 baudrate: int = 19200, faults: FaultPlan | None = None):
        self.length_m, self.zero_hook = length_m, zero
        self.metres_per_count, self.offset_m = float(metres_per_count), float(offset_m)
        self.counts_per_turn, self.word_order = int(counts_per_turn), word_order
        self.device_id, self.host, self.port = int(device_id), host, int(port)
        self.baudrate, self.rtu = int(baudrate), rtu
        self.faults = faults if faults is not None else FaultPlan()
        self.rtu_port: str | None = None
        self.zero_calls = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._bridge_thread: threading.Thread | None = None
        self._tcp: ModbusTcpServer | None = None
        self._rtu_server: ModbusSerialServer | None = None
        self._fds: list[int] = []
        self._stop = threading.Event()

    # -- register access (runs in the server loop) --------------------------------
    def counts(self) -> int:
        return round((self.length_m() - self.offset_m) / self.metres_per_count)

    async def _action(self, fc, start, address, count, registers, set_values):
        f = self.faults
        if not f.drawwire_answers():       # a lost answer: none is ever sent
            await asyncio.Event().wait()   # (cancelled when the server stops)
        # a read (no values to set) samples the length when asked: a late answer carries it
        c = self.counts() if set_values is None else None
        if f.late_s > 0:
            await asyncio.sleep(f.late_s)
        if f.modbus_exception:
            return ExcCodes(f.modbus_exception)
        if fc not in (3, 6):
            return ExcCodes.ILLEGAL_FUNCTION
        if set_values is not None:                       # function 06 on 0x0008
            if address != REG_ZERO or list(set_values) != [1]:
                return ExcCodes.ILLEGAL_VALUE
            # the hook first: the simulated robot captures its anchor there, so
            # the length read afterwards is the one at the new zero
            if self.zero_hook is not None:
                self.zero_hook()
            self.offset_m = self.length_m()
            self.zero_calls += 1
            return None
        base = REG_COUNT - start
        registers[base:base + 2] = split_words(c, self.word_order)
        registers[REG_TURNS - start] = (c // self.counts_per_turn) & 0xFFFF
        return None

    def _device(self) -> SimDevice:
        return SimDevice(self.device_id, action=self._action, simdata=[
            SimData(REG_COUNT, count=3, values=0, datatype=DataType.REGISTERS, readonly=True),
            SimData(REG_ZERO, values=0, datatype=DataType.REGISTERS)])

    # -- lifecycle --------------------------------------------------------------------
    def start(self) -> "SimDrawWire":
        ready = threading.Event()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="sim draw-wire",
                                        daemon=True)
        self._thread.start()
        if not ready.wait(10) or self._tcp is None:
            self.stop()
            raise RuntimeError(f"draw-wire simulator failed to start on {self.host}:{self.port}")
        return self

    def stop(self) -> None:
        """Shut the servers and the RTU bridge down (idempotent)."""
        self._stop.set()
        if self._loop is not None and self._thread is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        for t in (self._thread, self._bridge_thread):
            if t is not None:
                t.join(timeout=5)
        self._thread = self._bridge_thread = None
        for fd in self._fds:
            os.close(fd)
        self._fds = []

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _run(self, ready: threading.Event) -> None:
        self._loop = loop = asyncio.new_event_loop()
        try:
            loop.run_until_complete(self._serve(ready))
            loop.run_forever()
            for server in (self._tcp, self._rtu_server):
                if server is not None:
                    loop.run_until_complete(server.shutdown())
            tasks = asyncio.all_tasks(loop)
            for task in tasks:
                task.cancel()
            loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
        finally:
            ready.set()
            loop.close()

    async def _serve(self, ready: threading.Event) -> None:
        await self._listen_tcp()
        if self.rtu:
            m_srv, s_srv = os.openpty()
            m_cli, s_cli = os.openpty()
            for fd in (s_srv, s_cli):
                tty.setraw(fd)
            self._fds = [m_srv, s_srv, m_cli, s_cli]
            self.rtu_port = os.ttyname(s_cli)
            self._rtu_server = ModbusSerialServer(self._device(), port=os.ttyname(s_srv),
                                                  baudrate=self.baudrate)
            await self._rtu_server.serve_forever(background=True)
            self._bridge_thread = threading.Thread(target=self._bridge, args=(m_cli, m_srv),
                                                   daemon=True, name="sim draw-wire rtu bridge")
            self._bridge_thread.start()
        asyncio.get_running_loop().create_task(self._watch())
        ready.set()

    async def _listen_tcp(self) -> None:
        self._tcp = ModbusTcpServer(self._device(), address=(self.host, self.port))
        await self._tcp.serve_forever(background=True)
        self.port = self._tcp.transport.sockets[0].getsockname()[1]

    async def _apply_faults(self) -> None:
        if self.faults.drawwire_down and self._tcp is not None:
            self._tcp.close()                         # listener and its connections
            self._tcp = None
        elif not self.faults.drawwire_down and self._tcp is None:
            await self._listen_tcp()

    async def _watch(self) -> None:
        while True:
            await self._apply_faults()
            await asyncio.sleep(0.02)

    def apply_faults(self) -> None:
        """Apply ``drawwire_down`` now (otherwise within 20 ms)."""
        asyncio.run_coroutine_threadsafe(self._apply_faults(), self._loop).result(5)

    def drop_connections(self) -> None:
        """Close every open TCP connection once (the listener stays up)."""
        async def drop():
            if self._tcp is not None:
                for conn in list(self._tcp.active_connections.values()):
                    conn.close()
        asyncio.run_coroutine_threadsafe(drop(), self._loop).result(5)

    def _bridge(self, a: int, b: int) -> None:
        """Copy bytes between the two pty masters, dropping them while down."""
        peer = {a: b, b: a}
        while not self._stop.is_set():
            try:
                readable = select.select([a, b], [], [], 0.05)[0]
                for fd in readable:
                    data = os.read(fd, 4096)
                    if not self.faults.drawwire_down:
                        os.write(peer[fd], data)
            except OSError:
                if self._stop.is_set():
                    return
                self._stop.wait(0.05)


def main(argv: list[str] | None = None) -> None:
    """Child-process entry. Commands (one JSON object a line, keys combinable):
    ``length`` (m), ``offset`` (m at count 0), ``word_order``, ``faults`` (dict),
    ``clear``, ``drop`` (close TCP connections once); ``{}`` just reports.
    The first line gives ``host``, ``port``, ``rtu_port``; answers give
    ``zero_calls``, ``offset_m`` and ``counts``."""
    ap = argparse.ArgumentParser(prog="drawwire_sim")
    ap.add_argument("--length", type=float, default=1.0, help="cable length (m)")
    ap.add_argument("--metres-per-count", type=float, default=1e-4)
    ap.add_argument("--offset", type=float, default=0.0, help="length (m) at count 0")
    ap.add_argument("--word-order", choices=("big", "little"), default="big")
    ap.add_argument("--port", type=int, default=0)
    a = ap.parse_args(argv)
    state = {"length": a.length}
    sim = SimDrawWire(lambda: state["length"], metres_per_count=a.metres_per_count,
                      offset_m=a.offset, word_order=a.word_order, port=a.port)
    with sim:
        print(json.dumps({"host": sim.host, "port": sim.port, "rtu_port": sim.rtu_port}),
              flush=True)
        for line in sys.stdin:
            try:
                cmd = json.loads(line)
                if "length" in cmd:
                    state["length"] = float(cmd["length"])
                if "clear" in cmd:
                    sim.faults.clear()
                if "faults" in cmd:
                    sim.faults.update(**cmd["faults"])
                if "offset" in cmd:
                    sim.offset_m = float(cmd["offset"])
                if "word_order" in cmd:
                    sim.word_order = cmd["word_order"]
                sim.apply_faults()
                if cmd.get("drop"):
                    sim.drop_connections()
                answer = {"ok": True, "zero_calls": sim.zero_calls, "offset_m": sim.offset_m,
                          "counts": sim.counts()}
            except (ValueError, KeyError, TypeError) as e:
                answer = {"error": f"{type(e).__name__}: {e}"}
            print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main()
