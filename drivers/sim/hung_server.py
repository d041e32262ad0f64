"""A TCP server that accepts connections and never says a word: a hung socketcand (or
another service listening on the bus's port), for the tests and the adversarial sweep that
check a driver gives up in time and names the device."""
from __future__ import annotations

import socket
import threading


class HungServer:
    """Listens on 127.0.0.1 (:attr:`port`), accepts every connection, sends nothing."""

    def __init__(self, backlog: int = 64):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(backlog)
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        threading.Thread(target=self._serve, name="hung server", daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                self.conns.append(self.sock.accept()[0])
            except OSError:
                return

    def close(self) -> None:
        for c in self.conns + [self.sock]:
            c.close()
