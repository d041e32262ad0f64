"""Simulated Qualisys Track Manager: its real-time protocol over TCP (house style 2).

Wire format (little endian, as on QTM's port 22223): every packet is ``<II`` size
(bytes, header included) and type (0 error, 1 command, 2 XML, 3 data, 4 no more data,
6 event), then the body; a command, error or XML body is text ending in a NUL. On
connect the server sends the command ``QTM RT Interface connected``. Commands (case
does not matter)::

    Version 1.25              -> "Version set to 1.25"  (1.0 .. 1.25; else an error)
    QTMVersion                -> "QTM Version is ..."
    ByteOrder                 -> "Byte order is little endian"
    GetState                  -> event packet (1: connected)
    GetParameters General 3D  -> XML <QTM_Parameters_Ver_1.25> with <General><Frequency>
                                 and <The_3D><Labels>n</Labels><Label><Name>..</Name></Label>..
    GetCurrentFrame 3D        -> one data packet
    StreamFrames AllFrames|Frequency:n|FrequencyDivisor:n 3D / StreamFrames Stop
    anything else             -> error packet "Parse error"

A data packet's body: ``<qII`` timestamp (us), frame number, component count; per
component ``<II`` size (bytes, this header included) and type (1: 3D), then ``<Ihh``
marker count, 2D drop rate, out-of-sync rate, then per marker ``<3f`` x, y, z (mm; NaN:
not seen), in the label list's order.

The frame number is ``floor(elapsed * frame_rate) + 1``: requests within one frame
period get the same frame (the same noise). The label list is the ``extra`` markers
(static, not on the tool, e.g. ``room_ref``) and then ``labels``, whose positions
``points_fn()`` gives (``(M, 3)`` m, the instrument's frame) plus Gaussian noise of
``noise`` (m per coordinate). Faults (:class:`MocapFaults`, settable at run time):
``occluded`` labels read NaN, ``late_s`` delays each frame's answer (the frame is that
of the request), ``drop_next`` closes the connection at the next request (once),
``drop_prob`` at each request with that probability (``rng``).
"""
from __future__ import annotations

import asyncio
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from xml.sax.saxutils import escape

import numpy as np

HEADER = struct.Struct("<II")
DATA_HEAD = struct.Struct("<qII")
COMPONENT = struct.Struct("<II")
THE_3D = struct.Struct("<Ihh")
ERROR, COMMAND, XML, DATA, NO_MORE_DATA, EVENT = 0, 1, 2, 3, 4, 6
COMPONENT_3D = 1
EVENT_CONNECTED = 1
WELCOME = "QTM RT Interface connected"
MAX_PACKET = 1 << 20
VERSIONS = (1.0, 1.25)      # the RT protocol versions served (inclusive)


def packet(kind: int, body: bytes) -> bytes:
    """One packet: ``<II`` size and type, then ``body``."""
    return HEADER.pack(HEADER.size + len(body), kind) + body


def text_packet(kind: int, text: str) -> bytes:
    return packet(kind, text.encode() + b"\0")


def data_packet(frame: int, timestamp_us: int, xyz_mm: np.ndarray) -> bytes:
    """A data packet with one 3D component of ``xyz_mm`` (``(K, 3)``, sent as float32)."""
    markers = np.ascontiguousarray(xyz_mm, dtype="<f4").tobytes()
    component = THE_3D.pack(len(xyz_mm), 0, 0) + markers
    body = (DATA_HEAD.pack(int(timestamp_us), int(frame), 1)
            + COMPONENT.pack(COMPONENT.size + len(component), COMPONENT_3D) + component)
    return packet(DATA, body)


@dataclass
class MocapFaults:
    """What goes wrong with the simulated QTM; all off by default.

    occluded:  labels read NaN (not seen) in every frame.
    late_s:    delay (s) before each frame is answered.
    drop_next: close the connection at the next request (then cleared).
    drop_prob: probability of closing the connection at each request.
    """

    occluded: set[str] = field(default_factory=set)
    late_s: float = 0.0
    drop_next: bool = False
    drop_prob: float = 0.0

    def update(self, **changes) -> None:
        """Set fields by name; a bad name or value is a KeyError/ValueError naming it, and
        nothing is set."""
        names = {"occluded", "late_s", "drop_next", "drop_prob"}
        values = {}
        for k, v in changes.items():
            if k not in names:
                raise KeyError(f"unknown fault {k!r} (known: {', '.join(sorted(names))})")
            if k == "occluded":
                if isinstance(v, (str, bytes)) or not all(isinstance(s, str) for s in v):
                    raise ValueError(f"fault occluded: {v!r} is not a set of labels")
                v = set(v)
            elif k == "drop_next":
                if not isinstance(v, bool):
                    raise ValueError(f"fault drop_next: {v!r} is not true or false")
            else:
                hi = 1.0 if k == "drop_prob" else 60.0
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v <= hi:
                    raise ValueError(f"fault {k}: {v!r} is not a number from 0 to {hi:g}")
                v = float(v)
            values[k] = v
        for k, v in values.items():
            setattr(self, k, v)

    def clear(self) -> None:
        self.update(occluded=set(), late_s=0.0, drop_next=False, drop_prob=0.0)


class SimQTM:
    """A simulated QTM real-time server on ``host:port`` (0: a free port, the bound one in
    :attr:`port` after :meth:`start`), served from a background asyncio loop.

    points_fn:  callable -> ``(M, 3)`` true positions (m, instrument frame) of ``labels``.
    labels:     QTM labels of those points, in ``points_fn``'s order.
    noise:      std (m) of each coordinate of each marker in each frame.
    frame_rate: Hz.
    rng:        numpy Generator (noise and ``drop_prob``).
    extra:      label -> static position (m) of markers QTM sees that are not on the tool;
                they come first in QTM's label list.
    """

    def __init__(self, points_fn: Callable[[], np.ndarray], labels, *, noise: float = 0.0,
                 frame_rate: float = 100.0, rng: np.random.Generator | None = None,
                 extra: dict | None = None, host: str = "127.0.0.1", port: int = 0,
                 faults: MocapFaults | None = None):
        self.points_fn, self.labels = points_fn, tuple(labels)
        self.extra = {"room_ref": (0.5, 0.5, 0.0)} if extra is None else dict(extra)
        self.qtm_labels = tuple(self.extra) + self.labels
        if len(set(self.qtm_labels)) != len(self.qtm_labels):
            raise ValueError(f"labels must be distinct, got {self.qtm_labels!r}")
        if not frame_rate > 0:
            raise ValueError(f"frame_rate must be > 0 Hz, got {frame_rate!r}")
        self.noise, self.frame_rate = float(noise), float(frame_rate)
        self.rng = rng if rng is not None else np.random.default_rng()
        self.host, self.port = host, int(port)
        self.faults = faults if faults is not None else MocapFaults()
        self.requests = 0                 # commands received (all connections)
        self.connections = 0              # connections accepted
        self._t0 = time.monotonic()
        self._frame: tuple[int, np.ndarray] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._server: asyncio.AbstractServer | None = None
        self._writers: set[asyncio.StreamWriter] = set()

    # -- faults -------------------------------------------------------------------------------
    def set_faults(self, **kw) -> None:
        """:meth:`MocapFaults.update`; an occluded label QTM does not have is a ValueError."""
        unknown = set(kw.get("occluded", ())) - set(self.qtm_labels)
        if unknown:
            raise ValueError(f"fault occluded: no marker labelled {', '.join(sorted(unknown))} "
                             f"(labels: {', '.join(self.qtm_labels)})")
        self.faults.update(**kw)

    def clear_faults(self) -> None:
        self.faults.clear()

    # -- frames -------------------------------------------------------------------------------
    def frame_number(self) -> int:
        return int((time.monotonic() - self._t0) * self.frame_rate) + 1

    def frame(self) -> tuple[int, int, np.ndarray]:
        """The current frame: number, timestamp (us), ``(K, 3)`` positions (mm) of every
        label in QTM's order (occluded ones NaN). One noise draw per frame number."""
        fn = self.frame_number()
        if self._frame is None or self._frame[0] != fn:
            pts = np.asarray(self.points_fn(), dtype=float).reshape(len(self.labels), 3)
            static = np.asarray(list(self.extra.values()), dtype=float).reshape(-1, 3)
            xyz = np.vstack([static, pts])
            if self.noise > 0:
                xyz = xyz + self.rng.normal(0.0, self.noise, xyz.shape)
            self._frame = (fn, xyz / 1e-3)
        xyz = self._frame[1].copy()
        for k, lab in enumerate(self.qtm_labels):
            if lab in self.faults.occluded:
                xyz[k] = np.nan
        return fn, round((fn - 1) / self.frame_rate * 1e6), xyz

    def parameters_xml(self, parts) -> str:
        """The ``GetParameters`` answer for ``parts`` (``general``, ``3d``, ``all``)."""
        out = [f"<QTM_Parameters_Ver_{VERSIONS[1]}>"]
        if {"general", "all"} & parts:
            out.append(f"<General><Frequency>{self.frame_rate:g}</Frequency>"
                       "<Capture_Time>60</Capture_Time><Start_On_External_Trigger>False"
                       "</Start_On_External_Trigger></General>")
        if {"3d", "all"} & parts:
            out.append(f"<The_3D><AxisUpwards>+Z</AxisUpwards><Labels>{len(self.qtm_labels)}"
                       "</Labels>" + "".join(f"<Label><Name>{escape(lab)}</Name><RGBColor>"
                                             "65280</RGBColor></Label>"
                                             for lab in self.qtm_labels) + "</The_3D>")
        out.append(f"</QTM_Parameters_Ver_{VERSIONS[1]}>")
        return "".join(out)

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "SimQTM":
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), daemon=True,
                                        name="sim QTM")
        self._thread.start()
        if not ready.wait(10) or self._server is None:
            self.stop()
            raise RuntimeError(f"QTM simulator failed to start on {self.host}:{self.port}")
        return self

    def stop(self) -> None:
        """Close the listener and every connection (idempotent)."""
        if self._loop is not None and self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._thread = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _run(self, ready: threading.Event) -> None:
        self._loop = loop = asyncio.new_event_loop()
        try:
            self._server = loop.run_until_complete(
                asyncio.start_server(self._serve, self.host, self.port))
            self.port = self._server.sockets[0].getsockname()[1]
            ready.set()
            loop.run_forever()
            self._server.close()
            for w in list(self._writers):
                w.close()
            tasks = asyncio.all_tasks(loop)
            for task in tasks:
                task.cancel()
            if tasks:
                loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
        finally:
            ready.set()
            loop.close()

    # -- one connection -----------------------------------------------------------------------
    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        self._writers.add(writer)
        stream: asyncio.Task | None = None
        try:
            writer.write(text_packet(COMMAND, WELCOME))
            while True:
                size, kind = HEADER.unpack(await reader.readexactly(HEADER.size))
                if not HEADER.size <= size <= MAX_PACKET:
                    return
                body = await reader.readexactly(size - HEADER.size)
                self.requests += 1
                f = self.faults
                if f.drop_next or (f.drop_prob > 0 and self.rng.random() < f.drop_prob):
                    f.drop_next = False
                    return
                words = body.rstrip(b"\0").decode("latin-1").split() if kind == COMMAND else []
                cmd = words[0].lower() if words else ""
                if cmd == "streamframes":
                    if stream is not None:
                        stream.cancel()
                        stream = None
                    if len(words) >= 2 and words[1].lower() != "stop":
                        every = self._divisor(words[1])
                        if every is None or [w.lower() for w in words[2:]] != ["3d"]:
                            writer.write(text_packet(ERROR, "Parse error"))
                        else:
                            stream = asyncio.ensure_future(self._stream(writer, every))
                    continue
                if cmd == "getcurrentframe" and [w.lower() for w in words[1:]] == ["3d"]:
                    fn, ts, xyz = self.frame()
                    if f.late_s > 0:
                        await asyncio.sleep(f.late_s)
                    writer.write(data_packet(fn, ts, xyz))
                else:
                    writer.write(self._answer(words))
                await writer.drain()
        except (asyncio.IncompleteReadError, ConnectionError):
            pass
        finally:
            if stream is not None:
                stream.cancel()
            self._writers.discard(writer)
            writer.close()

    def _answer(self, words: list[str]) -> bytes:
        """The answer to a command other than frames."""
        cmd, args = (words[0].lower(), [w.lower() for w in words[1:]]) if words else ("", [])
        if cmd == "version" and len(args) == 1:
            try:
                v = float(args[0])
            except ValueError:
                v = math.nan
            if VERSIONS[0] <= v <= VERSIONS[1]:
                return text_packet(COMMAND, f"Version set to {args[0]}")
            return text_packet(ERROR, "Version NOT supported")
        if cmd == "qtmversion" and not args:
            return text_packet(COMMAND, "QTM Version is 2.99 (build 1, simulated)")
        if cmd == "byteorder" and not args:
            return text_packet(COMMAND, "Byte order is little endian")
        if cmd == "getstate" and not args:
            return packet(EVENT, bytes([EVENT_CONNECTED]))
        if cmd == "getparameters" and args and set(args) <= {"all", "general", "3d"}:
            return text_packet(XML, self.parameters_xml(set(args)))
        return text_packet(ERROR, "Parse error")

    def _divisor(self, which: str) -> int | None:
        """Every how many frames a stream sends one (``AllFrames``, ``Frequency:n``,
        ``FrequencyDivisor:n``), or None for nonsense."""
        kind, _, n = which.lower().partition(":")
        try:
            if kind == "allframes" and not n:
                return 1
            if kind == "frequency":
                return max(1, round(self.frame_rate / float(n)))
            if kind == "frequencydivisor":
                return max(1, int(n))
        except (ValueError, ZeroDivisionError):
            return None
        return None

    async def _stream(self, writer: asyncio.StreamWriter, every: int) -> None:
        """Send every ``every``-th frame as it is taken, until cancelled."""
        last = None
        while True:
            fn, ts, xyz = self.frame()
            if fn != last and fn % every == 0:
                writer.write(data_packet(fn, ts, xyz))
                await writer.drain()
                last = fn
            next_t = self._t0 + fn / self.frame_rate
            await asyncio.sleep(max(0.0, next_t - time.monotonic()) + 1e-4)
