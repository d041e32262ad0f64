"""Motion capture: Qualisys Track Manager (QTM) over its real-time protocol (qtm-rt 3.x).

The station asks QTM for its current frame's labelled 3D markers (``GetCurrentFrame
3D``: positions in mm, float32, NaN for a marker not seen in that frame) until it has
``frames`` distinct frames (a repeated frame number is asked again), and takes each
marker's mean over the frames in which it was seen. On open it asks ``GetParameters
General 3D`` and maps each configured label (the points on the tool, in order) to its
index in QTM's label list (``<The_3D><Label><Name>``).

Channels ``m1_x, m1_y, m1_z, m2_x, ...`` (m, the instrument's frame), marker ``k`` being
``labels[k - 1]``. A marker seen in none of the frames reads NaN: that is a reading (the
tool turned away), not a fault. ``Sample.info``: ``frames`` (their numbers),
``timestamps_us`` (QTM's), ``seen`` (label -> frames it was seen in), ``std`` and
``drift`` (label -> ``(x, y, z)`` m: sample std over its frames, fitted change over
them), ``since`` (the first request).

The SDK is asyncio: each open starts a private event loop in a background thread, and
the synchronous methods run coroutines on it. A frame that does not come within the
timeout is a :class:`DeviceTimeout`, a dropped connection a :class:`DeviceError`; the
read after a drop connects anew (``reconnects`` counts those).
"""
from __future__ import annotations

import asyncio
import concurrent.futures
import math
import threading
import time
import xml.etree.ElementTree as ET

import numpy as np
import qtm_rt

from calibration.errors import ConfigError
from drivers.base import Device, Sample, log
from drivers.errors import DeviceError, DeviceTimeout

#: the RT protocol version asked for (the layout parsed here is that of 1.25)
PROTOCOL_VERSION = "1.25"
DEFAULT_PORT = 22223        # QTM's little-endian RT port
AXES = ("x", "y", "z")
MM = 1e-3                   # m per mm
#: s between requests when QTM repeats a frame and its frame rate is unknown
REPEAT_POLL_S = 0.001


def marker_channels(m: int) -> tuple[str, ...]:
    """The channels of ``m`` markers: ``m1_x, m1_y, m1_z, m2_x, ...``."""
    return tuple(f"m{k}_{a}" for k in range(1, m + 1) for a in AXES)


def parse_parameters(xml: str) -> tuple[list[str], float | None]:
    """QTM's 3D labels in its order and its frame rate (Hz, None where not given) from a
    ``GetParameters`` XML answer; ValueError where it has no ``<The_3D>``."""
    root = ET.fromstring(xml)
    the_3d = root.find("The_3D")
    if the_3d is None:
        raise ValueError("the parameters have no <The_3D> section")
    labels = [(lab.findtext("Name") or "").strip() for lab in the_3d.findall("Label")]
    freq = root.findtext("General/Frequency")
    try:
        rate = float(freq) if freq is not None else None
    except ValueError:
        rate = None
    return labels, (rate if rate and math.isfinite(rate) and rate > 0 else None)


def average_frames(xyz_mm: np.ndarray, t_s: np.ndarray):
    """Each marker over the frames in which it was seen.

    xyz_mm: ``(N, M, 3)`` positions (mm; NaN: not seen); t_s: ``(N,)`` frame times (s).
    Returns ``mean (M, 3)`` m (NaN where never seen), ``seen (M,)`` frame counts,
    ``std (M, 3)`` m (ddof 1; 0 for one frame, NaN for none) and ``drift (M, 3)`` m
    (least-squares slope over time times the span of its frames)."""
    xyz = np.asarray(xyz_mm, dtype=float) * MM
    t = np.asarray(t_s, dtype=float)
    ok = np.all(np.isfinite(xyz), axis=2)
    m = xyz.shape[1]
    mean, std, drift = (np.full((m, 3), np.nan) for _ in range(3))
    seen = ok.sum(axis=0)
    for j in range(m):
        v, tj = xyz[ok[:, j], j], t[ok[:, j]]
        if len(v) == 0:
            continue
        mean[j] = v.mean(axis=0)
        std[j] = v.std(axis=0, ddof=1) if len(v) > 1 else 0.0
        tc = tj - tj.mean()
        span = float(tj[-1] - tj[0])
        drift[j] = (tc @ (v - mean[j])) / float(tc @ tc) * span if span > 0 else 0.0
    return mean, seen, std, drift


class MotionCapture(Device):
    """QTM's labelled 3D markers; channels :func:`marker_channels` of ``len(labels)`` (m).

    host, port: QTM's real-time server (port 22223: little endian).
    labels:     QTM labels of the points on the tool, in the station's order.
    frames:     distinct frames averaged per read (N).
    timeout:    s one fresh frame (or the connection, or the parameters) may take
                before :class:`DeviceTimeout`.
    """

    unseen_is_nan = True      # a marker not seen reads NaN: a pose with fewer points

    def __init__(self, host: str, port: int = DEFAULT_PORT, labels=(), frames: int = 20,
                 timeout: float = 1.0, name: str = "motion capture"):
        labels = tuple(labels)
        if not labels or any(not isinstance(s, str) or not s for s in labels):
            raise ConfigError(f"expected at least one non-empty label, got {labels!r}",
                              key="mocap.labels")
        if len(set(labels)) != len(labels):
            raise ConfigError(f"labels must be distinct, got {labels!r}", key="mocap.labels")
        if not 1 <= int(frames) <= 1000:
            raise ConfigError(f"must be 1..1000, got {frames!r}", key="mocap.frames")
        super().__init__(name, timeout)
        self.host, self.port = host, int(port)
        self.where = f"{host}:{self.port}"
        self.labels, self.frames = labels, int(frames)
        self.channels = marker_channels(len(labels))
        self.qtm_labels: tuple[str, ...] = ()    # QTM's label list (after open)
        self.index: tuple[int, ...] = ()         # each label's index in it
        self.frame_rate: float | None = None     # QTM's, Hz (after open)
        self.reconnects = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._conn = None
        self._lost: asyncio.Future | None = None
        self._last_frame: int | None = None
        self._seq = 0

    # -- hooks ------------------------------------------------------------------------------
    def _open_internal(self) -> None:
        self._start_loop()
        try:
            self._run(self._connect(self.timeout), 2 * self.timeout)
        except BaseException:
            self._stop_loop()
            raise

    def _close_internal(self) -> None:
        try:
            if self._conn is not None:
                self._run(self._disconnect(), 1.0)
        finally:
            self._stop_loop()

    def _read_internal(self, timeout: float) -> Sample:
        since = time.monotonic()
        if self._conn is None or self._lost is None or self._lost.done():
            log.warning("%s: connecting to %s again (the connection was lost or timed out)",
                        self.name, self.where)
            self._run(self._connect(timeout), 2 * timeout)
            self.reconnects += 1
        got = self._run(self._read_frames(self.frames, timeout), timeout * self.frames)
        numbers = [fn for fn, _, _ in got]
        t_us = np.array([ts for _, ts, _ in got], dtype=float)
        mean, seen, std, drift = average_frames(np.stack([xyz for _, _, xyz in got]),
                                                t_us * 1e-6)
        values = {ch: float(v) for ch, v in zip(self.channels, mean.ravel())}
        self._seq += 1
        info = {"since": since, "frames": tuple(numbers), "timestamps_us": tuple(t_us.tolist()),
                "seen": {lab: int(n) for lab, n in zip(self.labels, seen)},
                "std": {lab: tuple(map(float, s)) for lab, s in zip(self.labels, std)},
                "drift": {lab: tuple(map(float, d)) for lab, d in zip(self.labels, drift)}}
        return Sample(time.monotonic(), values, self._seq, info)

    # -- the event loop ---------------------------------------------------------------------
    def _start_loop(self) -> None:
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True,
                                        name=f"{self.name} event loop")
        self._thread.start()

    def _stop_loop(self) -> None:
        loop, thread = self._loop, self._thread
        self._loop = self._thread = self._conn = self._lost = None
        if loop is None:
            return
        loop.call_soon_threadsafe(loop.stop)
        if thread is not None:
            thread.join(timeout=5)
        if not loop.is_running():
            tasks = asyncio.all_tasks(loop)
            for task in tasks:
                task.cancel()
            if tasks:
                loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
            loop.close()

    def _run(self, coro, timeout: float):
        """Run ``coro`` on the private loop and wait for it (it keeps its own time; this
        waits a second longer only as a safety net)."""
        fut = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return fut.result(timeout + 1.0)
        except DeviceError:     # a DeviceTimeout is a TimeoutError too: not this one
            raise
        except concurrent.futures.TimeoutError:
            fut.cancel()
            raise DeviceTimeout(f"no answer from QTM at {self.where} within {timeout:g} s",
                                device=self.name) from None

    # -- coroutines (on the private loop) ---------------------------------------------------
    async def _connect(self, timeout: float) -> None:
        """Connect, ask the parameters, map the labels (a connection left over closed)."""
        await self._disconnect()
        lost = asyncio.get_running_loop().create_future()

        def on_disconnect(exc):
            if not lost.done():
                lost.set_result(exc)

        task = asyncio.ensure_future(qtm_rt.connect(
            self.host, self.port, version=PROTOCOL_VERSION, on_disconnect=on_disconnect,
            timeout=None))
        done, _ = await asyncio.wait({task, lost}, timeout=timeout,
                                     return_when=asyncio.FIRST_COMPLETED)
        if task not in done:
            task.cancel()
            what = ("closed the connection" if lost.done()
                    else f"did not answer within {timeout:g} s")
            raise (DeviceError if lost.done() else DeviceTimeout)(
                f"QTM at {self.where} {what} (connect, RT protocol {PROTOCOL_VERSION})",
                device=self.name)
        conn = task.result()
        if conn is None:
            raise DeviceError(f"cannot connect to QTM's real-time server at {self.where} "
                              f"(RT protocol {PROTOCOL_VERSION}): is QTM running with "
                              "real-time output on?", device=self.name)
        self._conn, self._lost = conn, lost
        try:
            xml = await self._ask(conn.get_parameters(["general", "3d"]), timeout,
                                  "GetParameters General 3D")
            try:
                qtm, rate = parse_parameters(bytes(xml).decode("utf-8", "replace"))
            except (ET.ParseError, ValueError) as e:
                raise DeviceError(f"QTM's parameters cannot be read: {e}",
                                  device=self.name) from None
            missing = [lab for lab in self.labels if lab not in qtm]
            if missing:
                raise DeviceError(
                    f"QTM has no marker labelled {', '.join(map(repr, missing))} (QTM's "
                    f"labels: {', '.join(qtm) or 'none'})", device=self.name)
        except BaseException:
            await self._disconnect()
            raise
        self.qtm_labels, self.frame_rate = tuple(qtm), rate
        self.index = tuple(qtm.index(lab) for lab in self.labels)
        log.info("%s: QTM at %s, labels %s at %s of %d, %s Hz", self.name, self.where,
                 self.labels, self.index, len(qtm), rate)

    async def _disconnect(self) -> None:
        conn, lost = self._conn, self._lost
        self._conn = None
        if conn is not None and conn.has_transport():
            conn.disconnect()
            if lost is not None:      # let the transport close (connection_lost runs)
                await asyncio.wait([lost], timeout=1.0)

    async def _ask(self, request, timeout: float, what: str, limit: float | None = None):
        """The answer to one request within ``timeout`` s, or DeviceTimeout (naming
        ``limit``, default ``timeout``; the connection is closed, so that the next request
        is not answered behind the late one: the next read connects anew) / DeviceError
        (connection lost, QTM's error packet)."""
        if self._conn is None or not self._conn.has_transport() or self._lost.done():
            request.close()     # never sent
            raise DeviceError(f"connection to QTM at {self.where} lost ({what})",
                              device=self.name)
        task = asyncio.ensure_future(request)
        done, _ = await asyncio.wait({task, self._lost}, timeout=max(timeout, 0.0),
                                     return_when=asyncio.FIRST_COMPLETED)
        if task in done:
            try:
                return task.result()
            except qtm_rt.QRTCommandException as e:
                if not self._conn.has_transport():
                    raise DeviceError(f"connection to QTM at {self.where} lost ({what})",
                                      device=self.name) from None
                raise DeviceError(f"QTM refused {what}: {e.value!r}", device=self.name) from None
        task.cancel()
        if self._lost.done():
            raise DeviceError(f"connection to QTM at {self.where} lost ({what})",
                              device=self.name)
        await self._disconnect()
        raise DeviceTimeout(f"no answer from QTM at {self.where} within "
                            f"{timeout if limit is None else limit:g} s ({what})",
                            device=self.name)

    async def _read_frames(self, n: int, timeout: float) -> list:
        """``n`` distinct frames ``(number, timestamp_us, (M, 3) mm)``; each may take
        ``timeout`` s, repeats of the frame before included."""
        loop = asyncio.get_running_loop()
        poll = 0.25 / self.frame_rate if self.frame_rate else REPEAT_POLL_S
        got: list = []
        for _ in range(n):
            deadline = loop.time() + timeout
            while True:
                packet = await self._ask(self._conn.get_current_frame(["3d"]),
                                         deadline - loop.time(), "GetCurrentFrame 3D", timeout)
                fn = packet.framenumber
                if fn != self._last_frame and all(fn != g[0] for g in got):
                    break
                if loop.time() + poll >= deadline:
                    raise DeviceTimeout(f"no new frame from QTM at {self.where} within "
                                        f"{timeout:g} s (frame {fn} repeated: is QTM "
                                        "measuring?)", device=self.name)
                await asyncio.sleep(poll)
            self._last_frame = fn
            got.append((fn, packet.timestamp, self._markers(packet)))
        return got

    def _markers(self, packet) -> np.ndarray:
        """The configured markers' ``(M, 3)`` positions (mm) in a data packet."""
        component = packet.get_3d_markers()
        if component is None:
            raise DeviceError(f"frame {packet.framenumber} has no 3D component",
                              device=self.name)
        markers = component[1]
        if len(markers) != len(self.qtm_labels):
            raise DeviceError(f"frame {packet.framenumber} has {len(markers)} 3D markers, "
                              f"QTM's label list {len(self.qtm_labels)}: the labels changed "
                              "in QTM (reconnect)", device=self.name)
        return np.array([(markers[i].x, markers[i].y, markers[i].z) for i in self.index],
                        dtype=float)
