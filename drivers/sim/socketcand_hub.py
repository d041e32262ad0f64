"""A virtual CAN bus over TCP that speaks the socketcand protocol (raw mode).

Every client is a CAN controller on one shared bus: a frame one client sends
is delivered to every *other* client, as on a real bus (no echo). The wire
dialogue is exactly what python-can's ``socketcand`` interface expects
(``can/interfaces/socketcand/socketcand.py``)::

    hub -> client   < hi >
    client -> hub   < open can0 >        hub -> client  < ok >
    client -> hub   < rawmode >          hub -> client  < ok >
    client -> hub   < send 181 6 27 2 e8 3 0 0 >      (ID, DLC, data bytes in hex)
    hub -> others   < frame 181 1717171717.123456 2702E8030000 >

The client checks each handshake answer with one ``recv()`` and an exact
comparison, so frames for a client are held back (not lost) until it has sent
a frame itself or ``GRACE_S`` has passed after its ``< ok >`` to ``< rawmode >``.

Bounded: at most ``max_clients`` connections, a message longer than
``MAX_MESSAGE`` characters drops its sender, a client whose unsent output
exceeds ``max_backlog`` bytes (it stopped reading) is dropped. A client that
disconnects only leaves the bus.

Use :class:`SocketcandHub` (``start()``/``stop()``, ``port``) in a thread, or
:func:`serve` (blocking) in a separate process; ``python -m
drivers.sim.socketcand_hub --port 29536`` runs one from the shell.
"""
from __future__ import annotations

import argparse
import logging
import selectors
import socket
import threading
import time

log = logging.getLogger("drivers.sim.socketcand_hub")

MAX_MESSAGE = 256
GRACE_S = 0.1


class _Client:
    def __init__(self, sock: socket.socket, addr):
        self.sock = sock
        self.addr = addr
        self.inbuf = ""
        self.outbuf = bytearray()
        self.stage = "hello"          # hello -> opened -> raw
        self.live_at: float | None = None  # monotonic time from which frames are forwarded
        self.held: list[str] = []          # frames waiting for live_at


class SocketcandHub:
    """A socketcand-protocol server on ``host:port`` acting as one CAN bus.

    host, port:  where to listen (``port=0``: an ephemeral port, read ``.port``).
    channel:     the bus name clients must open (``< open can0 >``).
    max_clients: connections accepted at once; more are refused.
    max_backlog: bytes of unsent output a slow client may accumulate.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, channel: str = "can0",
                 max_clients: int = 64, max_backlog: int = 1 << 20):
        self.host = host
        self.channel = channel
        self.max_clients = int(max_clients)
        self.max_backlog = int(max_backlog)
        self.frames = 0                      # frames forwarded (for diagnostics)
        self._listener = socket.create_server((host, int(port)), backlog=16)
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._clients: dict[socket.socket, _Client] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._closed = False

    # -- lifecycle ------------------------------------------------------------
    def start(self) -> "SocketcandHub":
        """Serve in a daemon thread; returns self."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.serve_forever, name=f"socketcand-hub:{self.port}",
                                            daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close every connection (idempotent)."""
        self._stop.set()
        try:
            self._wake_w.send(b"x")
        except OSError:
            pass
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._close_all()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    @property
    def endpoint(self) -> dict:
        """python-can keyword arguments reaching this hub."""
        return {"interface": "socketcand", "host": self.host, "port": self.port, "channel": self.channel}

    def serve_forever(self) -> None:
        """Run the bus until :meth:`stop` (blocking)."""
        self._sel.register(self._listener, selectors.EVENT_READ, "accept")
        self._sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        log.info("socketcand hub on %s:%d (channel %s)", self.host, self.port, self.channel)
        try:
            while not self._stop.is_set():
                for key, mask in self._sel.select(timeout=GRACE_S / 2):
                    if key.data == "accept":
                        self._accept()
                    elif key.data == "wake":
                        self._wake_r.recv(64)
                    else:
                        client = key.data
                        if mask & selectors.EVENT_READ:
                            self._on_readable(client)
                        if mask & selectors.EVENT_WRITE and client.sock in self._clients:
                            self._flush(client)
                self._release_held()
        finally:
            self._close_all()

    # -- connections ------------------------------------------------------------
    def _accept(self) -> None:
        try:
            sock, addr = self._listener.accept()
        except OSError:
            return
        if len(self._clients) >= self.max_clients:
            log.warning("hub full (%d clients): refusing %s", self.max_clients, addr)
            sock.close()
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = _Client(sock, addr)
        self._clients[sock] = client
        self._sel.register(sock, selectors.EVENT_READ, client)
        self._write(client, "< hi >")

    def _drop(self, client: _Client, why: str) -> None:
        if self._clients.pop(client.sock, None) is None:
            return
        log.info("hub: client %s left (%s)", client.addr, why)
        try:
            self._sel.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()

    def _close_all(self) -> None:
        if self._closed:
            return
        self._closed = True
        for client in list(self._clients.values()):
            self._drop(client, "hub stopped")
        for s in (self._listener, self._wake_r, self._wake_w):
            s.close()
        self._sel.close()

    # -- input --------------------------------------------------------------------
    def _on_readable(self, client: _Client) -> None:
        try:
            data = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            self._drop(client, str(e))
            return
        if not data:
            self._drop(client, "disconnected")
            return
        client.inbuf += data.decode("ascii", "replace")
        while client.sock in self._clients:
            start = client.inbuf.find("<")
            if start < 0:
                client.inbuf = ""
                break
            end = client.inbuf.find(">", start)
            if end < 0:
                client.inbuf = client.inbuf[start:]
                if len(client.inbuf) > MAX_MESSAGE:
                    self._drop(client, "message too long")
                break
            message, client.inbuf = client.inbuf[start + 1:end].split(), client.inbuf[end + 1:]
            self._on_message(client, message)

    def _on_message(self, client: _Client, words: list[str]) -> None:
        cmd = words[0] if words else ""
        if client.stage == "hello" and cmd == "open":
            if len(words) == 2 and words[1] == self.channel:
                client.stage = "opened"
                self._write(client, "< ok >")
            else:
                self._write(client, "< error could not open bus >")
        elif client.stage == "opened" and cmd == "rawmode":
            client.stage = "raw"
            client.live_at = time.monotonic() + GRACE_S
            self._write(client, "< ok >")
        elif client.stage == "raw" and cmd == "send":
            client.live_at = min(client.live_at or 0.0, time.monotonic())
            self._release_held()
            self._on_send(client, words[1:])
        elif cmd == "echo":
            self._write(client, "< echo >")
        else:
            self._write(client, f"< error unexpected {cmd or 'message'} >")

    def _on_send(self, client: _Client, args: list[str]) -> None:
        try:
            can_id, dlc = int(args[0], 16), int(args[1], 16)
            data = bytes(int(b, 16) for b in args[2:])
            if len(data) != dlc or dlc > 8 or len(args[0]) not in (3, 8):
                raise ValueError
        except (ValueError, IndexError):
            self._write(client, "< error malformed send >")
            return
        ident = f"{can_id & 0x7FF:03X}" if len(args[0]) == 3 else f"{can_id & 0x1FFFFFFF:08X}"
        frame = f"< frame {ident} {time.time():.6f} {data.hex().upper()} >"
        now = time.monotonic()
        self.frames += 1
        for other in list(self._clients.values()):
            if other is client or other.stage != "raw":
                continue
            if other.live_at <= now:
                self._write(other, frame)
            elif len(other.held) < 10000:
                other.held.append(frame)

    def _release_held(self) -> None:
        now = time.monotonic()
        for client in list(self._clients.values()):
            if client.held and client.live_at <= now:
                held, client.held = client.held, []
                self._write(client, "".join(held))

    # -- output -------------------------------------------------------------------
    def _write(self, client: _Client, text: str) -> None:
        client.outbuf += text.encode("ascii")
        if len(client.outbuf) > self.max_backlog:
            self._drop(client, f"not reading ({len(client.outbuf)} bytes pending)")
            return
        self._flush(client)

    def _flush(self, client: _Client) -> None:
        try:
            sent = client.sock.send(client.outbuf)
            del client.outbuf[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError as e:
            self._drop(client, str(e))
            return
        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.outbuf else 0)
        self._sel.modify(client.sock, events, client)


def serve(host: str = "127.0.0.1", port: int = 0, channel: str = "can0", ready=None,
          stop_event=None) -> None:
    """Run a hub in this thread until ``stop_event`` (a ``threading``/``multiprocessing``
    Event) is set, or forever. ``ready(port)`` is called once listening."""
    hub = SocketcandHub(host, port, channel).start()
    try:
        if ready is not None:
            ready(hub.port)
        while stop_event is None or not stop_event.is_set():
            time.sleep(0.2)
    finally:
        hub.stop()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="socketcand-protocol virtual CAN bus on TCP")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=29536)
    p.add_argument("--channel", default="can0")
    a = p.parse_args(argv)
    try:
        serve(a.host, a.port, a.channel, ready=lambda port: print(f"socketcand hub on {a.host}:{port}",
                                                                    flush=True))
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
