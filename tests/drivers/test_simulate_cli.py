"""``app.py simulate`` as a standalone process: standard clients (a plain canopen
master, a plain pymodbus client, a plain serial reader) talk to it using only
the endpoints file, and ``app.py devices check`` reads it through the station's
drivers."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import canopen
import pytest
import serial
from pymodbus.client import ModbusTcpClient

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "fixtures" / "eds" / "agebot_cia402.eds"


@pytest.fixture(scope="module")
def simulator(tmp_path_factory):
    ep = tmp_path_factory.mktemp("sim") / "endpoints.json"
    proc = subprocess.Popen([sys.executable, str(ROOT / "app.py"), "simulate", "--robot",
                             "agebot-sm", "--endpoints", str(ep)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 20
    while not ep.exists():
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "app.py simulate wrote no endpoints file"
        time.sleep(0.05)
    yield proc, ep, json.loads(ep.read_text())
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        proc.wait(10)
    proc.stderr.close()


def test_plain_canopen_master_reads_every_drive(simulator):
    _, _, ep = simulator
    c = ep["canopen"]
    network = canopen.Network()
    network.connect(interface=c["interface"], host=c["host"], port=c["port"],
                    channel=c["channel"])
    try:
        for nid in c["nodes"]:
            node = network.add_node(nid, str(EDS))
            assert node.sdo[0x1000].raw == 0x00020192            # CiA 402 drive
            assert isinstance(node.sdo["Position actual value"].raw, int)
    finally:
        network.disconnect()


def test_plain_pymodbus_client_reads_the_drawwire(simulator):
    _, _, ep = simulator
    d = ep["drawwire"]
    client = ModbusTcpClient(d["host"], port=d["port"], timeout=2)
    assert client.connect()
    try:
        rr = client.read_holding_registers(0, count=3, device_id=d["device_id"])
        assert not rr.isError() and len(rr.registers) == 3
    finally:
        client.close()


def test_plain_serial_reader_gets_valid_inclinometer_frames(simulator):
    _, _, ep = simulator
    i = ep["inclinometer"]
    with serial.Serial(i["port"], i["baudrate"], timeout=2) as port:
        data = port.read(200)
    starts = [k for k in range(len(data) - 10) if data[k] == 0x55 and data[k + 1] == 0x53
              and sum(data[k:k + 10]) & 0xFF == data[k + 10]]
    assert starts, data.hex()


def test_devices_check_reads_the_simulator_through_the_drivers(simulator):
    _, ep_path, _ = simulator
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "devices", "check",
                        "--config", str(ROOT / "fixtures" / "stations" / "sim-sm.toml"),
                        "--endpoints", str(ep_path), "--seconds", "0.3"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr + r.stdout
    assert "OK    canopen" in r.stdout and "OK    inclinometer" in r.stdout
    assert "OK    draw-wire" in r.stdout and "qm1" in r.stdout and "distance" in r.stdout


def test_devices_check_names_a_missing_device(simulator, tmp_path):
    _, _, ep = simulator
    broken = dict(ep, drawwire=dict(ep["drawwire"], port=1))   # nothing listens on port 1
    path = tmp_path / "endpoints.json"
    path.write_text(json.dumps(broken))
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "devices", "check",
                        "--config", str(ROOT / "fixtures" / "stations" / "sim-sm.toml"),
                        "--endpoints", str(path), "--seconds", "0.2"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert "FAIL  draw-wire" in r.stdout and "drawwire.host/port" in r.stdout
    assert "OK    canopen" in r.stdout


def test_simulate_stops_cleanly_on_sigterm(simulator):
    proc, ep_path, _ = simulator
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(10) == 0
    assert not ep_path.exists()        # no stale endpoints left behind


def test_simulate_endpoints_into_a_missing_folder_is_one_line(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "app.py"), "simulate", "--robot", "agebot-sm",
                        "--endpoints", str(tmp_path / "missing" / "ep.json")],
                       capture_output=True, text=True, timeout=60)
    err = r.stderr.strip().splitlines()
    assert r.returncode != 0 and len(err) == 1, r.stderr
    assert "--endpoints" in err[0] and "does not exist" in err[0] and "missing" in err[0]
    assert not (tmp_path / "missing").exists()
