"""The simulator's control port: JSON lines over TCP on 127.0.0.1, the ``control``
endpoint of ``app.py simulate`` (cli.md).

One command a line, a JSON object; every command answers one JSON line:
``{"ok": true, ...}`` or ``{"error": "..."}`` (a bad command, or any failure: never a
dropped connection). The commands and their answers are those of
:meth:`drivers.sim.sim_station.SimStation.command` (fault injection, the simulated
truth). :class:`ControlServer` serves a station's commands (it takes the station as an
attribute and imports nothing of it); :class:`SimControl` is the client tests, demos and
the headless run use.
"""
from __future__ import annotations

import json
import logging
import socket
import socketserver
from typing import Any

from calibration.errors import ConfigError

log = logging.getLogger("drivers.sim")


class ControlServer(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True
    station: Any        # the SimStation whose ``command`` answers each line


class ControlHandler(socketserver.StreamRequestHandler):
    def handle(self) -> None:
        for line in self.rfile:
            if not line.strip():
                continue
            try:
                answer = self.server.station.command(json.loads(line))
            except (ValueError, KeyError, TypeError) as e:   # a bad command: its answer
                answer = {"error": f"{type(e).__name__}: {e}"}
            except Exception as e:  # any failure is an answer, never a dropped connection
                log.exception("control command %r failed", line)
                answer = {"error": f"{type(e).__name__}: {e}"}
            self.wfile.write((json.dumps(answer) + "\n").encode())
            self.wfile.flush()


class SimControl:
    """Client of a running simulator's control port (tests, demos, the headless run)."""

    def __init__(self, host: str, port: int, timeout: float = 10.0):
        self._sock = socket.create_connection((host, int(port)), timeout=timeout)
        self._file = self._sock.makefile("rwb")

    @classmethod
    def from_endpoints(cls, endpoints: dict) -> "SimControl":
        c = endpoints.get("control")
        if not c:
            raise ConfigError("the endpoints give no simulator control port", key="control")
        return cls(c["host"], c["port"])

    def call(self, **command) -> dict:
        self._file.write((json.dumps(command) + "\n").encode())
        self._file.flush()
        line = self._file.readline()
        if not line:
            raise ConnectionError("the simulator closed its control port")
        answer = json.loads(line)
        if "error" in answer:
            raise RuntimeError(f"simulator: {answer['error']}")
        return answer

    def close(self) -> None:
        for f in (self._file, self._sock):
            try:
                f.close()
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
