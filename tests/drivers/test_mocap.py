"""Motion capture: the QTM driver (qtm-rt) against the simulated QTM real-time server over
TCP, the server's wire format read raw, the ``[mocap]`` config section, and the rig's
snapshot of a pose with the motion capture's mean of N frames."""
from __future__ import annotations

import math
import re
import socket
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from calibration.errors import ConfigError
from drivers.base import Sample
from drivers.check import reading_text
from drivers.config import load_station_config, parse_station_config
from drivers.config_mocap import MocapConfig
from drivers.errors import DeviceError, DeviceTimeout
from drivers.mocap import MotionCapture, average_frames, marker_channels
from drivers.rig import PoseSnapshot, Rig, with_mocap
from drivers.sim.mocap_sim import SimQTM
from drivers.snapshot import Snapshot

STATIONS = Path(__file__).resolve().parents[2] / "fixtures" / "stations"
TOOL = ("tool_a", "tool_b", "tool_c")
POINTS = np.array([[0.10, 0.20, 1.00], [0.25, -0.05, 1.10], [-0.30, 0.15, 0.90]])  # m
NOISE = 2e-4          # m per coordinate per frame
RATE = 400.0          # Hz: 20 frames in 50 ms


@pytest.fixture
def qtm():
    """A simulated QTM (its own, on a free port) seeing the tool's points and ``room_ref``."""
    sim = SimQTM(lambda: POINTS, TOOL, noise=NOISE, frame_rate=RATE,
                 rng=np.random.default_rng(5), extra={"room_ref": (1.0, 1.0, 0.0)}).start()
    yield sim
    sim.stop()


def device(sim, labels=TOOL, **kw) -> MotionCapture:
    kw.setdefault("timeout", 0.5)
    return MotionCapture("127.0.0.1", sim.port, labels=labels, **kw)


def positions(sample, m) -> np.ndarray:
    return np.array([[sample.values[f"m{k}_{a}"] for a in "xyz"] for k in range(1, m + 1)])


# -- the driver through qtm-rt ----------------------------------------------------------------
def test_labels_map_in_the_configured_order_and_the_mean_is_of_distinct_frames(qtm):
    order = ("tool_c", "tool_a")        # not QTM's order; tool_b and room_ref left out
    with device(qtm, labels=order, frames=20) as mc:
        assert mc.qtm_labels == ("room_ref",) + TOOL and mc.index == (3, 1)
        assert mc.frame_rate == RATE
        s1, s2 = mc.read(), mc.read()
    assert mc.channels == marker_channels(2) == ("m1_x", "m1_y", "m1_z", "m2_x", "m2_y", "m2_z")
    assert list(s1.values) == list(mc.channels)
    np.testing.assert_allclose(positions(s1, 2), POINTS[[2, 0]], atol=5 * NOISE / math.sqrt(20))
    frames = s1.info["frames"] + s2.info["frames"]
    assert len(s1.info["frames"]) == 20 and len(set(frames)) == 40
    assert list(frames) == sorted(frames)            # increasing, none repeated
    assert s1.info["seen"] == {"tool_c": 20, "tool_a": 20}
    for label in order:
        assert np.all(np.array(s1.info["std"][label]) == pytest.approx(NOISE, rel=0.6))
    assert s2.seq > s1.seq and s1.info["since"] <= s1.t


def test_an_occluded_marker_is_nan_and_the_others_are_fine(qtm):
    with device(qtm, frames=5) as mc:
        qtm.set_faults(occluded={"tool_b"})
        s = mc.read()
        assert all(math.isnan(s.values[f"m2_{a}"]) for a in "xyz")
        np.testing.assert_allclose(positions(s, 3)[[0, 2]], POINTS[[0, 2]], atol=5 * NOISE)
        assert s.info["seen"] == {"tool_a": 5, "tool_b": 0, "tool_c": 5}
        text = reading_text(mc, s).split("; ")
        assert text[1] == "tool_b not seen" and len(text) == 3
        assert re.fullmatch(r"tool_a \((99|100)\.\d, (199|200)\.\d, (999|1000)\.\d\) mm",
                            text[0]), text
        qtm.clear_faults()
        assert not math.isnan(mc.read().values["m2_x"])


def test_frames_later_than_the_timeout_are_a_device_timeout(qtm):
    with device(qtm, frames=3) as mc:
        qtm.set_faults(late_s=0.6)
        t0 = time.monotonic()
        with pytest.raises(DeviceTimeout, match=r"^motion capture: no answer from QTM at "
                                                r"127\.0\.0\.1:\d+ within 0\.2 s"):
            mc.read(timeout=0.2)
        assert time.monotonic() - t0 < 0.5
        qtm.clear_faults()      # the late answer is not taken for the next frame
        s = mc.read()
        assert mc.reconnects == 1 and len(set(s.info["frames"])) == 3


def test_a_repeated_frame_is_asked_again_and_a_frozen_one_times_out():
    slow = SimQTM(lambda: POINTS, TOOL, frame_rate=40.0).start()
    frozen = SimQTM(lambda: POINTS, TOOL, frame_rate=0.2).start()   # a new frame every 5 s
    try:
        with device(slow, frames=3) as mc:
            t0 = time.monotonic()
            s = mc.read()
            fr = s.info["frames"]
            assert len(fr) == 3 and fr[0] < fr[1] < fr[2]
            assert time.monotonic() - t0 >= 1 / 40      # two new frames: a period at least
        with device(frozen, frames=2) as mc:
            with pytest.raises(DeviceTimeout, match=r"^motion capture: no new frame from QTM "
                                                    r"at .* within 0\.3 s \(frame 1 repeated"):
                mc.read(timeout=0.3)
    finally:
        slow.stop()
        frozen.stop()


def test_a_dropped_connection_is_a_device_error_and_reopening_works(qtm):
    mc = device(qtm, frames=4)
    mc.open()
    qtm.set_faults(drop_next=True)
    with pytest.raises(DeviceError, match=r"^motion capture: connection to QTM at .* lost"):
        mc.read()
    mc.close()
    mc.close()                                        # idempotent
    assert not mc.is_open and qtm.connections == 1
    with mc:
        assert len(mc.read().info["frames"]) == 4
    assert qtm.connections == 2
    mc.open()
    qtm.set_faults(drop_next=True)
    with pytest.raises(DeviceError):
        mc.read()
    assert mc.read().info["seen"]["tool_a"] == 4      # the next read connects anew
    assert mc.reconnects == 1
    mc.close()


def test_a_label_qtm_does_not_have_is_one_line_naming_it(qtm):
    mc = device(qtm, labels=("tool_a", "tool_x"))
    with pytest.raises(DeviceError) as e:
        mc.open()
    assert str(e.value) == ("motion capture: QTM has no marker labelled 'tool_x' (QTM's "
                            "labels: room_ref, tool_a, tool_b, tool_c)")
    assert not mc.is_open


def test_no_qtm_is_a_device_error_naming_the_device():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(DeviceError, match=r"^motion capture: cannot connect to QTM's "
                                          rf"real-time server at 127\.0\.0\.1:{port}"):
        MotionCapture("127.0.0.1", port, labels=TOOL, timeout=0.5).open()
    with pytest.raises(ConfigError, match="mocap.labels"):
        MotionCapture("127.0.0.1", port, labels=("a", "a"))


# -- the wire, raw ------------------------------------------------------------------------------
def _packet(sock) -> tuple[int, bytes]:
    head = b""
    while len(head) < 8:
        head += sock.recv(8 - len(head))
    size, kind = struct.unpack("<II", head)
    body = b""
    while len(body) < size - 8:
        body += sock.recv(size - 8 - len(body))
    return kind, body


def _send(sock, text: str) -> None:
    body = text.encode() + b"\0"
    sock.sendall(struct.pack("<II", 8 + len(body), 1) + body)


def test_the_server_speaks_qtms_wire_format(qtm):
    with socket.create_connection(("127.0.0.1", qtm.port), timeout=2) as sock:
        assert _packet(sock) == (1, b"QTM RT Interface connected\0")
        _send(sock, "Version 1.25")
        assert _packet(sock) == (1, b"Version set to 1.25\0")
        _send(sock, "ByteOrder")
        assert _packet(sock) == (1, b"Byte order is little endian\0")
        _send(sock, "GetParameters 3D")
        kind, xml = _packet(sock)
        assert kind == 2 and xml.endswith(b"\0")
        assert re.findall(rb"<Name>(\w+)</Name>", xml) == [b"room_ref", *(t.encode() for t in TOOL)]
        _send(sock, "GetCurrentFrame 3D")
        kind, body = _packet(sock)
        assert kind == 3 and len(body) == 16 + 8 + 8 + 4 * 12
        timestamp, frame, components = struct.unpack_from("<qII", body, 0)
        assert components == 1 and frame >= 1 and timestamp == round((frame - 1) / RATE * 1e6)
        size, ctype = struct.unpack_from("<II", body, 16)
        assert (size, ctype) == (8 + 8 + 4 * 12, 1)
        count, _drop, _sync = struct.unpack_from("<Ihh", body, 24)
        xyz = np.frombuffer(body, "<f4", 12, 32).reshape(4, 3)
        assert count == 4
        np.testing.assert_allclose(xyz[1:], POINTS * 1e3, atol=5 * NOISE * 1e3)
        np.testing.assert_allclose(xyz[0], (1000.0, 1000.0, 0.0), atol=5 * NOISE * 1e3)
        _send(sock, "Fly to the moon")
        assert _packet(sock) == (0, b"Parse error\0")
        _send(sock, "Version 9.0")
        assert _packet(sock)[0] == 0


def test_streaming_through_the_sdk(qtm):
    import asyncio

    import qtm_rt

    async def stream():
        conn = await qtm_rt.connect("127.0.0.1", qtm.port)
        got = []
        await conn.stream_frames(frames="frequencydivisor:2", components=["3d"],
                                 on_packet=lambda p: got.append(p.framenumber))
        await asyncio.sleep(0.05)
        await conn.stream_frames_stop()
        conn.disconnect()
        return got

    got = asyncio.run(stream())
    assert len(got) >= 3 and all(fn % 2 == 0 for fn in got) and got == sorted(set(got))


# -- averaging and the rig's snapshot ------------------------------------------------------------
def test_average_frames_counts_the_frames_each_marker_was_seen_in():
    xyz = np.array([[[1.0, 2, 3], [np.nan] * 3], [[3.0, 2, 3], [np.nan] * 3],
                    [[np.nan] * 3, [5.0, 5, 5]]])                                 # mm
    mean, seen, std, drift = average_frames(xyz, np.array([0.0, 0.01, 0.02]))
    assert list(seen) == [2, 1]
    np.testing.assert_allclose(mean, [[2e-3, 2e-3, 3e-3], [5e-3, 5e-3, 5e-3]])
    np.testing.assert_allclose(std[0], [math.sqrt(2) * 1e-3, 0, 0])
    np.testing.assert_allclose(drift[0], [2e-3, 0, 0])
    assert list(std[1]) == [0, 0, 0]


def test_the_snapshot_takes_the_mean_of_markers_seen_in_half_the_frames():
    mc = MotionCapture("127.0.0.1", labels=("a", "b"), frames=4)
    values = dict(zip(mc.channels, (0.1, 0.2, 0.3, 0.4, 0.5, 0.6)))
    sample = Sample(10.5, values, 1, {"since": 10.0, "frames": (7, 8, 9, 10),
                                      "seen": {"a": 2, "b": 1},
                                      "std": {"a": (1e-4,) * 3, "b": (0.0,) * 3},
                                      "drift": {"a": (0.0,) * 3, "b": (0.0,) * 3}})
    snap = Snapshot(mean={"qm1": 1.0}, std={"qm1": 0.0}, drift={"qm1": 0.0}, samples=5,
                    t_start="t0", t_end="t1", duration=0.1, devices={"qm1": "canopen"})
    out = with_mocap(snap, mc, sample)
    assert isinstance(out, PoseSnapshot) and out.samples == 5
    assert out.mean["qm1"] == 1.0 and out.mean["m1_z"] == 0.3 and out.std["m1_x"] == 1e-4
    assert all(math.isnan(out.mean[f"m2_{a}"]) for a in "xyz")
    assert out.devices["m2_y"] == "motion capture" and out.duration == pytest.approx(0.6)
    assert out.info["motion capture"]["seen"] == {"a": 2, "b": 1}


def test_the_rig_builds_the_motion_capture_from_the_config():
    text = (STATIONS / "example-real.toml").read_text()
    import tomllib

    data = tomllib.loads(text)
    data["mocap"] = {"host": "127.0.0.1", "labels": ["tool_a", "tool_b"], "frames": 8,
                     "volume": {"min": [-2, -2, 0], "max": [2, 2, 2.5]}}
    rig = Rig(parse_station_config(data, "lab.toml"))
    assert rig.mocap is rig.devices[-1] and rig.mocap.name == "motion capture"
    assert (rig.mocap.port, rig.mocap.frames, rig.mocap.labels) == (22223, 8, ("tool_a", "tool_b"))
    assert load_station_config(STATIONS / "example-real.toml").mocap is None


# -- the config section ---------------------------------------------------------------------------
def _mocap(**changes):
    import tomllib

    data = tomllib.loads((STATIONS / "example-real.toml").read_text())
    data["mocap"] = {"host": "qtm.lab", "labels": ["a", "b"],
                     "volume": {"min": [-1, -1, 0], "max": [1, 1, 2]}, **changes}
    return parse_station_config(data, "lab.toml")


def test_the_config_section_parses_with_defaults_and_placeholders():
    c = _mocap(outward=[[0, 0, 1], [1, 0, 0]], viewpoint=[0, 0, 3], view_angle_deg=45)
    assert c.mocap == MocapConfig(host="qtm.lab", labels=("a", "b"), volume_min=(-1, -1, 0),
                                  volume_max=(1, 1, 2), viewpoint=(0, 0, 3), view_angle_deg=45,
                                  outward=((0, 0, 1), (1, 0, 0)))
    m = _mocap().mocap
    assert (m.port, m.frames, m.timeout, m.viewpoint, m.view_angle_deg, m.outward) == \
        (22223, 20, 1.0, (0, 0, 0), 60, None)
    p = _mocap(host="@endpoints", port="@endpoints")
    assert p.mocap.host is None and {"mocap.host", "mocap.port"} <= set(p.unresolved)


@pytest.mark.parametrize("changes,expected", [
    ({"labels": []}, r"mocap\.labels: expected at least one label"),
    ({"labels": "a"}, r"mocap\.labels: expected a list"),
    ({"labels": ["a", ""]}, r"mocap\.labels\[1\]: expected a non-empty string"),
    ({"labels": ["a", "b", "a"]}, r"mocap\.labels: labels must be distinct \('a'"),
    ({"frames": 0}, r"mocap\.frames: 0 must be >= 1"),
    ({"frames": 1001}, r"mocap\.frames: 1001 must be <= 1000"),
    ({"timeout": 0}, r"mocap\.timeout: 0\.0 must be > 0"),
    ({"port": 70000}, r"mocap\.port: 70000 must be <= 65535"),
    ({"volume": {"min": [0, 0, 0]}}, r"mocap\.volume\.max: missing required key"),
    ({"volume": {"min": [0, 0, 0], "max": [1, 0, 1]}}, r"mocap\.volume\.max: every max"),
    ({"volume": {"min": [0, 0], "max": [1, 1, 1]}}, r"mocap\.volume\.min: expected a list of 3"),
    ({"viewpoint": [0, 0]}, r"mocap\.viewpoint: expected a list of 3"),
    ({"view_angle_deg": 200}, r"mocap\.view_angle_deg: 200\.0 must be <= 180"),
    ({"outward": [[0, 0, 1]]}, r"mocap\.outward: expected a list of 2"),
    ({"outward": [[0, 0, 1], [0, "x", 0]]}, r"mocap\.outward\[1\]\[1\]: expected a finite"),
    ({"outward": [[0, 0, 1], [0, 0, 0]]}, r"mocap\.outward: vector 1 \('b'\) is zero"),
    ({"colour": "red"}, r"mocap\.colour: unknown key"),
])
def test_config_errors_name_the_key(changes, expected):
    with pytest.raises(ConfigError) as e:
        _mocap(**changes)
    assert str(e.value).startswith("lab.toml: ") and "\n" not in str(e.value)
    assert re.search(expected, str(e.value)), str(e.value)


def test_a_missing_volume_or_labels_is_named():
    import tomllib

    data = tomllib.loads((STATIONS / "example-real.toml").read_text())
    data["mocap"] = {"host": "qtm.lab", "labels": ["a"]}
    with pytest.raises(ConfigError, match=r"^lab\.toml: mocap\.volume: missing required key"):
        parse_station_config(data, "lab.toml")
    data["mocap"] = {"host": "qtm.lab", "volume": {"min": [0, 0, 0], "max": [1, 1, 1]}}
    with pytest.raises(ConfigError, match=r"^lab\.toml: mocap\.labels: missing required key"):
        parse_station_config(data, "lab.toml")
