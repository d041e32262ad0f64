"""Inclinometer driver against its simulated twin in a separate process (over a pty)."""
from __future__ import annotations

import math

import pytest
import serial

from calibration.errors import ConfigError
from drivers.errors import DeviceError, DeviceTimeout
from drivers.inclinometer import (FRAME_LEN, FrameParser, Inclinometer, accel_frame,
                                  angles_frame, encode_frame)
from drivers.sim.inclinometer_sim import SimProcess

ROLL, PITCH, YAW = 12.5, -33.25, 100.0          # degrees, fixed in the simulator
RES = math.radians(180.0 / 32768)               # one count of an angle frame (rad)


@pytest.fixture(scope="module")
def sim():
    with SimProcess("drivers.sim.inclinometer_sim", "--angles", str(ROLL), str(PITCH), str(YAW),
                    "--rate", "50", "--seed", "7", "--tcp") as proc:
        yield proc


@pytest.fixture
def port(sim):
    sim.call(clear=True)
    yield sim.info["port"]
    sim.call(clear=True)


# -- parser (pure) --------------------------------------------------------------------

def test_parser_decodes_angles_and_acceleration():
    p = FrameParser()
    frames = p.feed(angles_frame(ROLL, PITCH, YAW) + accel_frame(0.5, -0.25, 1.0, 31.5))
    assert [f.type for f in frames] == [0x53, 0x51]
    assert frames[0].angles_deg == pytest.approx((ROLL, PITCH, YAW), abs=180 / 32768)
    assert frames[1].accel_g == pytest.approx((0.5, -0.25, 1.0), abs=16 / 32768)
    assert frames[1].temperature_c == pytest.approx(31.5)
    assert p.stats == {"frames_ok": 2, "checksum_errors": 0, "bytes_skipped": 0}


def test_parser_resynchronises_after_garbage():
    p = FrameParser()
    garbage = bytes([0x00, 0x55, 0x13, 0xFF, 0x55])   # false headers included
    frames = p.feed(garbage + angles_frame(1.0, 2.0, 3.0))
    assert len(frames) == 1 and frames[0].angles_deg[2] == pytest.approx(3.0, abs=0.01)
    assert p.bytes_skipped == len(garbage)


def test_parser_drops_and_counts_checksum_errors():
    bad = bytearray(angles_frame(45.0, 45.0, 45.0))
    bad[4] ^= 0x01
    good = angles_frame(-10.0, 0.0, 0.0)
    p = FrameParser()
    frames = p.feed(bytes(bad) + good)
    assert [f.angles_deg[0] for f in frames] == [pytest.approx(-10.0, abs=0.01)]
    assert p.checksum_errors == 1 and p.frames_ok == 1


def test_parser_joins_frames_split_across_reads():
    stream = angles_frame(5.0, 6.0, 7.0) + accel_frame(0, 0, 1, 20) + angles_frame(8, 9, 10)
    p = FrameParser()
    frames = []
    for i in range(0, len(stream), 4):            # 4-byte chunks cut every frame
        frames += p.feed(stream[i:i + 4])
    assert [f.type for f in frames] == [0x53, 0x51, 0x53]
    assert frames[2].angles_deg == pytest.approx((8, 9, 10), abs=0.01)
    assert p.feed(b"") == [] and p.stats["bytes_skipped"] == 0


def test_encode_frame_checksum():
    f = encode_frame(0x53, (1, -1, 0, 0))
    assert len(f) == FRAME_LEN and f[0] == 0x55 and f[10] == sum(f[:10]) & 0xFF


# -- driver over the wire -------------------------------------------------------------

def test_read_maps_axes_with_sign_and_offset(port):
    axes = {"tilt": ("pitch", 1, 0.0), "r": ("roll", -1, 0.25), "heading": ("yaw", 1, -0.1)}
    with Inclinometer(port, axes) as inc:
        assert inc.channels == ("tilt", "r", "heading")
        s = inc.read()
    assert s.values["tilt"] == pytest.approx(math.radians(PITCH), abs=RES)
    assert s.values["r"] == pytest.approx(-math.radians(ROLL) + 0.25, abs=RES)
    assert s.values["heading"] == pytest.approx(math.radians(YAW) - 0.1, abs=RES)
    assert s.info["raw_deg"] == pytest.approx((ROLL, PITCH, YAW), abs=0.01)


def test_wrist_configuration_and_fresh_samples(port):
    with Inclinometer(port, {"roll": ("roll", 1, 0.0), "pitch": ("pitch", 1, 0.0)},
                      baudrate=115200) as inc:
        samples = [inc.read() for _ in range(3)]
    assert [s.seq for s in samples] == sorted({s.seq for s in samples})   # strictly fresh
    assert samples[-1].values == pytest.approx({"roll": math.radians(ROLL),
                                                "pitch": math.radians(PITCH)}, abs=RES)
    assert samples[-1].info["accel_g"][2] > 0.5                             # gravity, mostly z


def test_corrupted_and_dropped_frames_never_yield_a_wrong_value(sim, port):
    sim.call(faults={"corrupt_prob": 0.4, "drop_prob": 0.3})
    with Inclinometer(port, {"tilt": ("pitch", 1, 0.0)}, timeout=2.0) as inc:
        for _ in range(25):
            assert inc.read().values["tilt"] == pytest.approx(math.radians(PITCH), abs=RES)
        stats = inc.stats
    assert stats["checksum_errors"] > 0 and stats["bytes_skipped"] > 0 and stats["frames_ok"] > 0


def test_silent_port_times_out_naming_the_port(sim, port):
    with Inclinometer(port, {"tilt": ("pitch", 1, 0.0)}) as inc:
        inc.read()
        sim.call(faults={"inclinometer_silent": True})
        with pytest.raises(DeviceTimeout, match=port):
            for _ in range(10):              # frames already under way may still arrive
                inc.read(timeout=0.3)
        sim.call(faults={"inclinometer_silent": False})
        assert inc.read(timeout=2.0).values["tilt"] == pytest.approx(math.radians(PITCH), abs=RES)


def test_tcp_bridge(sim, port):
    with Inclinometer(sim.info["url"], {"tilt": ("pitch", -1, 0.0)}) as inc:
        assert inc.read().values["tilt"] == pytest.approx(-math.radians(PITCH), abs=RES)


def test_plain_serial_reader_finds_angle_frames(port):
    with serial.Serial(port, 9600, timeout=0.1) as ser:
        ser.reset_input_buffer()
        buf = b""
        for _ in range(100):
            buf += ser.read(64)
            i = buf.find(b"\x55\x53")
            if 0 <= i <= len(buf) - 11 and sum(buf[i:i + 10]) & 0xFF == buf[i + 10]:
                break
        else:
            pytest.fail(f"no 55 53 frame in {buf.hex()}")
    raw = [int.from_bytes(buf[i + 2 + 2 * k:i + 4 + 2 * k], "little", signed=True)
           for k in range(3)]
    assert [r / 32768 * 180 for r in raw] == pytest.approx([ROLL, PITCH, YAW], abs=0.01)


def test_errors_and_idempotent_close(tmp_path, port):
    with pytest.raises(ConfigError, match="axes.tilt"):
        Inclinometer(port, {"tilt": ("heave", 1, 0.0)})
    with pytest.raises(ConfigError, match="sign"):
        Inclinometer(port, {"tilt": ("pitch", 2, 0.0)})
    missing = str(tmp_path / "ttyNOPE")
    with pytest.raises(DeviceError, match="ttyNOPE"):
        Inclinometer(missing, {"tilt": ("pitch", 1, 0.0)}).open()
    inc = Inclinometer(port, {"tilt": ("pitch", 1, 0.0)})
    with pytest.raises(DeviceError, match="not open"):
        inc.read()
    inc.open()
    inc.close()
    inc.close()
    assert not inc.is_open
