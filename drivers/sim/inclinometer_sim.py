"""Simulated WitMotion-style inclinometer on a pseudo-terminal (house style 2).

:class:`SimInclinometer` writes angle (0x53) and acceleration (0x51) frames to
the master side of a pty; the driver opens the slave path (:attr:`port`) like a
real serial port. Optionally the same bytes go to TCP clients of a bridge on
127.0.0.1 (:attr:`url`, ``socket://...``). Faults from a shared
:class:`FaultPlan`: ``drop_prob`` (frame not sent), ``corrupt_prob`` (a data
byte flipped, so the checksum fails, plus occasional garbage before a frame),
``inclinometer_silent`` (nothing sent).

Run in its own process: ``python -m drivers.sim.inclinometer_sim --angles R P Y``
(see :func:`main`), or from a test with :class:`SimProcess`.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import random
import select
import socket
import subprocess
import sys
import threading
import tty
from collections.abc import Callable

from drivers.inclinometer import accel_frame, angles_frame
from drivers.sim.faults import FaultPlan


log = logging.getLogger(__name__)

class SimInclinometer:
    """A pty that streams inclinometer frames.

    angles_deg:    callable -> (roll, pitch, yaw) in degrees, called once per frame cycle.
    rate_hz:       frame cycles per second (one 0x51 and one 0x53 frame each).
    faults:        shared fault plan (a private one by default).
    temperature_c: reported temperature (degC).
    tcp:           also serve the stream on ``socket://127.0.0.1:<port>``.
    """

    def __init__(self, angles_deg: Callable[[], tuple[float, float, float]], *,
                 rate_hz: float = 20.0, faults: FaultPlan | None = None,
                 temperature_c: float = 25.0, tcp: bool = False, seed: int | None = None):
        self.angles_deg = angles_deg
        self.period = 1.0 / float(rate_hz)
        self.faults = faults if faults is not None else FaultPlan()
        self.temperature_c = float(temperature_c)
        self.port: str | None = None
        self.url: str | None = None
        self.frames_sent = 0
        self._tcp = tcp
        self._rng = random.Random(seed)
        self._master = self._slave = None
        self._listener: socket.socket | None = None
        self._clients: list[socket.socket] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "SimInclinometer":
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)   # no echo, no CR/LF translation: binary clean
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        if self._tcp:
            self._listener = socket.create_server(("127.0.0.1", 0))
            self._listener.setblocking(False)
            self.url = "socket://127.0.0.1:%d" % self._listener.getsockname()[1]
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sim inclinometer", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop streaming and close the pty (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for s in [*self._clients, self._listener]:
            if s is not None:
                s.close()
        self._clients, self._listener = [], None
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _frames(self) -> bytes:
        roll, pitch, yaw = self.angles_deg()
        r, p = math.radians(roll), math.radians(pitch)
        g = (-math.sin(p), math.sin(r) * math.cos(p), math.cos(r) * math.cos(p))
        out = b""
        for frame in (accel_frame(*g, self.temperature_c), angles_frame(roll, pitch, yaw)):
            f = self.faults
            if f.chance(f.drop_prob):
                continue
            if f.chance(f.corrupt_prob):       # a flipped data byte: checksum fails
                b = bytearray(frame)
                b[self._rng.randrange(2, 10)] ^= self._rng.randrange(1, 256)
                frame = bytes(b)
            if f.chance(f.corrupt_prob):       # line noise with a false header
                frame = bytes([0x55] + [self._rng.randrange(256)
                                        for _ in range(self._rng.randrange(0, 9))]) + frame
            out += frame
            self.frames_sent += 1
        return out

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self._tick()
            except Exception:        # a sensor talks on: one bad tick never ends the thread
                log.exception("simulated inclinometer: a frame failed")

    def _tick(self) -> None:
        self._accept()
        if self.faults.inclinometer_silent:
            return
        data = self._frames()
        try:
            os.write(self._master, data)
        except BlockingIOError:
            pass                           # nobody reads: a real sensor talks on anyway
        for c in list(self._clients):
            try:
                c.sendall(data)
            except OSError:
                self._clients.remove(c)
                c.close()

    def _accept(self) -> None:
        if self._listener is None:
            return
        while select.select([self._listener], [], [], 0)[0]:
            conn, _ = self._listener.accept()
            conn.setblocking(True)
            conn.settimeout(0.5)
            self._clients.append(conn)


class SimProcess:
    """A simulator in a child process (``python -m <module> <args>``), driven by
    one-line JSON commands on its stdin; each answers one JSON line.

    ``info`` is the simulator's first line (e.g. ``{"port": "/dev/pts/5"}``).
    """

    def __init__(self, module: str, *args: str, timeout: float = 10.0):
        self.timeout = timeout
        self._proc = subprocess.Popen([sys.executable, "-m", module, *args],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        try:
            self.info = self._answer()
        except Exception:
            self.close()
            raise

    def _answer(self) -> dict:
        if not select.select([self._proc.stdout], [], [], self.timeout)[0]:
            raise TimeoutError(f"simulator {self._proc.args} did not answer")
        line = self._proc.stdout.readline()
        if not line:
            raise RuntimeError(f"simulator {self._proc.args} exited ({self._proc.poll()})")
        return json.loads(line)

    def call(self, **command) -> dict:
        """Send one command (e.g. ``faults={"drop_prob": 0.5}``); return its answer."""
        self._proc.stdin.write((json.dumps(command) + "\n").encode())
        self._proc.stdin.flush()
        answer = self._answer()
        if "error" in answer:
            raise RuntimeError(f"simulator: {answer['error']}")
        return answer

    def close(self) -> None:
        """Stop the child (idempotent): stdin EOF, then terminate/kill if needed."""
        if self._proc.poll() is None:
            try:
                self._proc.stdin.close()
                self._proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self._proc.kill()
                self._proc.wait()
        for f in (self._proc.stdin, self._proc.stdout):
            f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def main(argv: list[str] | None = None) -> None:
    """Child-process entry: a fixed-angle sensor; commands ``faults``, ``angles``, ``stats``."""
    ap = argparse.ArgumentParser(prog="inclinometer_sim")
    ap.add_argument("--angles", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                    metavar=("ROLL", "PITCH", "YAW"), help="degrees")
    ap.add_argument("--rate", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--tcp", action="store_true")
    a = ap.parse_args(argv)
    state = {"angles": tuple(a.angles)}
    sim = SimInclinometer(lambda: state["angles"], rate_hz=a.rate, tcp=a.tcp, seed=a.seed,
                          faults=FaultPlan(seed=a.seed))
    with sim:
        print(json.dumps({"port": sim.port, "url": sim.url}), flush=True)
        for line in sys.stdin:
            try:
                cmd = json.loads(line)
                if "faults" in cmd:
                    sim.faults.update(**cmd["faults"])
                if "clear" in cmd:
                    sim.faults.clear()
                if "angles" in cmd:
                    state["angles"] = tuple(float(x) for x in cmd["angles"])
                answer = {"ok": True, "frames_sent": sim.frames_sent}
            except (ValueError, KeyError, TypeError) as e:
                answer = {"error": f"{type(e).__name__}: {e}"}
            print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main()
