"""The CAN bus under the station's ``canopen.Network``: opening it, closing it, and the
end of python-can's receive thread.

:func:`open_network` connects a network to the bus the python-can settings describe
(``interface``, ``channel`` and further ``can.Bus`` arguments): a socketcand server is
asked for its greeting first (a refused connection fails at once, a hung server within
:data:`CONNECT_TIMEOUT_S`), and python-can's connect, which has no timeout of its own, is
bounded by the same time. :class:`BusLoss` hears a bus that fails under the receive
thread; :func:`bus_error_text` says a CAN error in one line. Used by
:class:`drivers.canopen_nodes.CanopenNodes` (its open, close and health) and its
exchanges (:mod:`drivers.canopen_exchanges`). Times in seconds.
"""
from __future__ import annotations

import contextlib
import socket
import threading

import can
import canopen

from drivers.errors import DeviceError, DeviceTimeout

#: seconds a CAN bus may take to come up (the socketcand greeting, python-can's connect)
CONNECT_TIMEOUT_S = 3.0


def open_network(bus_config: dict, timeout: float, device: str) -> canopen.Network:
    """A ``canopen.Network`` connected to the bus ``bus_config`` describes (python-can
    ``can.Bus`` keyword arguments); ``timeout``: the device's SDO timeout (the bus gets
    at least :data:`CONNECT_TIMEOUT_S`); ``device`` names it in errors. A bus that
    cannot be opened is a :class:`DeviceError` naming its settings, one that does not
    come up in time a :class:`DeviceTimeout`."""
    network = canopen.Network()
    try:
        _server_answers(bus_config, timeout, device)
        _connect(network, bus_config, timeout, device)
    except DeviceError:
        raise
    except (can.CanError, OSError, ValueError, ImportError) as e:
        raise DeviceError(f"cannot open the CAN bus {_bus_text(bus_config)}: "
                          f"{bus_error_text(e)}",
                          device=device) from e
    return network


def close_network(network: canopen.Network) -> None:
    """Disconnect ``network`` quietly (its receive thread's error said already)."""
    if network.notifier is not None:
        network.notifier.exception = None   # said already; canopen would log it again
    with contextlib.suppress(Exception):
        network.disconnect()


def _bus_name(cfg: dict) -> str:
    """The bus in errors: ``CAN bus socketcand can0 at 127.0.0.1:29536``."""
    where = f" at {cfg['host']}:{cfg['port']}" if cfg.get("host") else ""
    return f"CAN bus {cfg.get('interface')} {cfg.get('channel')}{where}"


def _server_answers(cfg: dict, timeout: float, device: str) -> None:
    """A socketcand server that refuses the connection (not running, the cable or
    the simulator gone) is an OSError at once: python-can's socketcand interface
    would retry a refused connection for 10 s in a busy loop. One that accepts the
    connection and says nothing (a hung server, another service on that port) is a
    :class:`DeviceTimeout` within :data:`CONNECT_TIMEOUT_S`: python-can would wait
    for its greeting ``< hi >`` for ever."""
    if cfg.get("interface") != "socketcand" or not (cfg.get("host") and cfg.get("port")):
        return
    limit = max(CONNECT_TIMEOUT_S, timeout)
    with socket.create_connection((cfg["host"], int(cfg["port"])), timeout=limit) as s:
        s.settimeout(limit)
        got = b""
        try:
            while b">" not in got and len(got) < 256:
                chunk = s.recv(256)
                if not chunk:
                    raise DeviceError(f"{_bus_name(cfg)}: the server closed the connection "
                                      "without the socketcand greeting", device=device)
                got += chunk
        except TimeoutError:
            raise DeviceTimeout(f"{_bus_name(cfg)}: the server accepted the connection but "
                                f"sent no socketcand greeting within {limit:g} s (a hung "
                                "server, or not socketcand on that port)",
                                device=device) from None
        if not got.strip().startswith(b"< hi >"):
            raise DeviceError(f"{_bus_name(cfg)}: not a socketcand server (it said "
                              f"{got[:40]!r})", device=device)


def _connect(network, cfg: dict, timeout: float, device: str) -> None:
    """``network.connect`` bounded by :data:`CONNECT_TIMEOUT_S` (python-can's
    connect has no timeout of its own): a bus that does not come up in time is a
    :class:`DeviceTimeout` naming it; the connect left behind is shut down when
    it ends."""
    done, box = threading.Event(), {}

    def connect():
        try:
            network.connect(**cfg)
        except BaseException as e:          # handed to the caller
            box["error"] = e
        finally:
            done.set()
            if box.get("abandoned"):
                with contextlib.suppress(Exception):
                    network.disconnect()

    limit = max(CONNECT_TIMEOUT_S, timeout)
    threading.Thread(target=connect, name=f"{device} connect", daemon=True).start()
    if not done.wait(limit):
        box["abandoned"] = True
        raise DeviceTimeout(f"{_bus_name(cfg)}: no connection within {limit:g} s",
                            device=device)
    if "error" in box:
        raise box["error"]


class BusLoss(can.Listener):
    """Hears the end of python-can's receive thread: a bus that fails under it (the
    socketcand server or its cable gone, a connection reset) is handed to ``on_error``.
    Handled here, the thread ends without an unhandled exception (whose traceback would
    land on the operator's terminal); its ``notifier.exception`` stays, and
    :meth:`CanopenNodes.check_health` names it at the device's next call."""

    def __init__(self, network):
        self.network = network

    def on_message_received(self, msg) -> None:
        pass

    def on_error(self, exc: Exception) -> None:
        notifier = self.network.notifier
        if notifier is not None:
            notifier.stop(timeout=-1)     # ends the receive loop; never joins this thread


def bus_error_text(e: BaseException) -> str:
    """A CAN error in one line: python-can folds the failing call's traceback into the
    message of the error its receive thread ends with; the root cause is said instead
    (``connection reset by peer``)."""
    root = e
    while root.__cause__ is not None or root.__context__ is not None:
        root = root.__cause__ or root.__context__
    text = str(root).split("Traceback (most recent call last)")[0].strip()
    if isinstance(root, OSError) and root.strerror:
        text = root.strerror
    first = text.splitlines()[0].strip() if text else type(root).__name__
    return first[:1].lower() + first[1:]


def _bus_text(bus: dict) -> str:
    """A CAN bus's settings for people: ``socketcand can0 at 127.0.0.1:29536``."""
    b = dict(bus)
    where = f"{b.pop('host')}:{b.pop('port')}" if "host" in b and "port" in b else ""
    head = " ".join(str(b.pop(k)) for k in ("interface", "channel") if b.get(k) is not None)
    rest = ", ".join(f"{k} {v}" for k, v in b.items() if v is not None and not isinstance(v, dict))
    return " ".join(x for x in (head, f"at {where}" if where else "", f"({rest})" if rest else "")
                    if x) or "(no settings)"
