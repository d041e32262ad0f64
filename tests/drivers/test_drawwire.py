"""Draw-wire driver against its simulated twin (pymodbus server) in a separate process."""
from __future__ import annotations

import time

import pytest
from pymodbus.client import ModbusTcpClient

from calibration.errors import ConfigError
from drivers.drawwire import EXCEPTION_TEXT, DrawWire, combine_words, split_words
from drivers.errors import DeviceError, DeviceTimeout, ProtocolError
from drivers.sim.drawwire_sim import SimProcess

MPC = 1e-4            # metres per count (sim and driver)
OFFSET = 0.5          # cable length (m) at count 0 (sim and driver)
LONG = OFFSET + 123456 * MPC      # a count > 0xFFFF: both words non-zero


@pytest.fixture(scope="module")
def sim():
    with SimProcess("drivers.sim.drawwire_sim", "--length", str(LONG), "--offset", str(OFFSET),
                    "--metres-per-count", str(MPC)) as proc:
        yield proc


@pytest.fixture
def server(sim):
    sim.call(clear=True, word_order="big", offset=OFFSET)   # zero() moves the origin
    yield sim
    sim.call(clear=True, word_order="big", offset=OFFSET)


def tcp(server, **kw) -> DrawWire:
    return DrawWire(host="127.0.0.1", tcp_port=server.info["port"], metres_per_count=MPC,
                    offset_m=OFFSET, **kw)


def rtu(server, **kw) -> DrawWire:
    return DrawWire(port=server.info["rtu_port"], metres_per_count=MPC, offset_m=OFFSET, **kw)


def test_word_helpers_round_trip():
    for order in ("big", "little"):
        assert combine_words(split_words(0x0001E240, order), order) == 0x0001E240
    assert split_words(0x0001E240, "big") == [0x0001, 0xE240]


@pytest.mark.parametrize("make", [tcp, rtu], ids=["tcp", "rtu"])
def test_read_distance(server, make):
    server.call(length=1.2345)
    with make(server) as dw:
        s1, s2 = dw.read(), dw.read()
    assert dw.channels == ("distance",)
    assert s1.values["distance"] == pytest.approx(1.2345, abs=MPC)
    assert s1.info["count"] == 7345 and s1.info["turns"] == 7345 // 2000
    assert s2.seq > s1.seq


@pytest.mark.parametrize("order", ["big", "little"])
def test_word_order_both_ways(server, order):
    server.call(length=LONG, word_order=order)
    with tcp(server, word_order=order) as dw:
        assert dw.read().info["count"] == 123456
        assert dw.read().values["distance"] == pytest.approx(LONG, abs=MPC)
    other = "little" if order == "big" else "big"
    with tcp(server, word_order=other) as dw:          # mismatched config: words swapped
        swapped = combine_words(split_words(123456, order), other)
        assert dw.read().info["count"] == (swapped - (1 << 32) if swapped >= 1 << 31 else swapped)


def test_count_below_the_zero_point_is_negative(server):
    """UINT32 on the wire, two's complement in meaning: just below zero is -n counts,
    never 4294 m of cable."""
    server.call(length=2.0)
    with tcp(server) as dw:
        dw.zero()
        server.call(length=2.0 - 7 * MPC)
        s = dw.read()
        assert s.info["count"] == -7
        assert s.values["distance"] == pytest.approx(OFFSET - 7 * MPC, abs=MPC / 10)


@pytest.mark.parametrize("make", [tcp, rtu], ids=["tcp", "rtu"])
def test_zero_at_current_position(server, make):
    server.call(length=2.0)
    with make(server) as dw:
        before = server.call()["zero_calls"]
        dw.zero()
        assert server.call()["zero_calls"] == before + 1
        assert dw.read().values["distance"] == pytest.approx(OFFSET, abs=MPC)
        server.call(length=2.25)
        assert dw.read().values["distance"] == pytest.approx(OFFSET + 0.25, abs=MPC)


@pytest.mark.parametrize("code", [1, 2, 3, 4, 6])
@pytest.mark.parametrize("make", [tcp, rtu], ids=["tcp", "rtu"])
def test_modbus_exception_becomes_protocol_error(server, make, code):
    server.call(faults={"modbus_exception": code})
    with make(server) as dw:
        with pytest.raises(ProtocolError) as err:
            dw.read()
    assert err.value.code == code and err.value.text == EXCEPTION_TEXT[code]
    assert dw.name in str(err.value) and EXCEPTION_TEXT[code] in str(err.value)


def test_dropped_link_is_reconnected_and_recorded(server, caplog):
    server.call(length=1.0)
    with tcp(server) as dw:
        dw.read()
        server.call(drop=True)
        with caplog.at_level("WARNING", logger="drivers"):
            assert dw.read().values["distance"] == pytest.approx(1.0, abs=MPC)
        assert dw.reconnects == 1
        assert any("recovered" in r.getMessage() for r in caplog.records)


def test_server_down_gives_a_clear_error_then_recovers(server):
    server.call(length=1.0)
    with tcp(server, retries=2, backoff_s=0.01) as dw:
        dw.read()
        server.call(faults={"drawwire_down": True})
        with pytest.raises(DeviceError, match=r"draw-wire 127\.0\.0\.1:\d+.*down after 2"):
            dw.read()
        server.call(faults={"drawwire_down": False})
        assert dw.read().values["distance"] == pytest.approx(1.0, abs=MPC)
        assert dw.reconnects == 1
    server.call(faults={"drawwire_down": True})
    with pytest.raises(DeviceError, match="cannot connect to Modbus TCP server"):
        tcp(server).open()


def test_rtu_silent_and_late_answers_time_out(server):
    with rtu(server) as dw:
        server.call(faults={"drawwire_down": True})
        with pytest.raises(DeviceTimeout, match=server.info["rtu_port"]):
            dw.read(timeout=0.3)
        server.call(clear=True)
        dw.read()
    with tcp(server) as dw:
        server.call(faults={"late_s": 1.0})
        with pytest.raises(DeviceTimeout, match="no answer"):
            dw.read(timeout=0.2)
        server.call(clear=True)
        assert dw.read().info["count"] == server.call()["counts"]


@pytest.mark.parametrize("make", [tcp, rtu], ids=["tcp", "rtu"])
def test_a_late_answer_is_never_taken_for_the_next_reading(server, make):
    """An answer that comes after its request timed out carries the length read when
    it was asked: the next reading must be the length now, never that one (Modbus RTU
    has no transaction id to tell the two apart)."""
    server.call(length=1.0)
    with make(server) as dw:
        dw.read()
        server.call(faults={"late_s": 1.0})
        with pytest.raises(DeviceTimeout, match="no answer"):
            dw.read(timeout=0.2)
        server.call(clear=True, length=1.5)
        time.sleep(1.0)                              # the late answer (1.0 m) is in
        assert dw.read(timeout=2.0).values["distance"] == pytest.approx(1.5, abs=MPC)
        assert dw.read(timeout=2.0).values["distance"] == pytest.approx(1.5, abs=MPC)


def test_plain_pymodbus_client_talks_to_the_simulator(server):
    server.call(length=LONG)
    client = ModbusTcpClient("127.0.0.1", port=server.info["port"], timeout=2, retries=0)
    try:
        assert client.connect()
        rr = client.read_holding_registers(0x0000, count=3, device_id=1)
        assert not rr.isError() and rr.registers == [0x0001, 0xE240, 123456 // 2000]
        assert client.read_holding_registers(0x0005, count=1, device_id=1).exception_code == 2
        assert client.write_registers(0x0008, [1], device_id=1).exception_code == 1  # fc 16
        assert client.write_register(0x0008, 7, device_id=1).exception_code == 3
    finally:
        client.close()


def test_config_errors_and_idempotent_close(server):
    with pytest.raises(ConfigError, match="word_order"):
        tcp(server, word_order="middle")
    with pytest.raises(ConfigError, match="exactly one"):
        DrawWire(metres_per_count=MPC)
    dw = tcp(server)
    with pytest.raises(DeviceError, match="not open"):
        dw.read()
    dw.open()
    dw.close()
    dw.close()


def test_an_rtu_port_is_opened_with_the_configured_parity_and_stop_bits():
    """The config's parity and stopbits reach the serial port (a sensor set to 8E2 talks
    8E2); a value the port cannot take is a config error naming the section."""
    dw = DrawWire(metres_per_count=1e-5, port="/dev/null-no-such-port", parity="E", stopbits=2)
    params = dw._client.comm_params
    assert (params.parity, params.stopbits, params.bytesize) == ("E", 2, 8)
    with pytest.raises(ConfigError, match="parity"):
        DrawWire(metres_per_count=1e-5, port="/dev/x", parity="X")
