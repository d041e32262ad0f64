"""Station config: the fixtures parse, every error names the file and the key path."""
from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest

from calibration.errors import ConfigError
from drivers.config import (CanopenConfig, DrawwireConfig, InclinometerConfig, SnapshotConfig,
                            StationConfig, load_station_config, parse_station_config)
from drivers.endpoints import load_endpoints, with_endpoints

STATIONS = Path(__file__).resolve().parents[2] / "fixtures" / "stations"
ENDPOINTS = {  # cli.md's example
    "canopen": {"interface": "socketcand", "host": "127.0.0.1", "port": 29536,
                "channel": "can0", "nodes": [1, 2, 3, 4]},
    "inclinometer": {"port": "/dev/pts/5", "baudrate": 9600},
    "drawwire": {"host": "127.0.0.1", "port": 15020, "device_id": 1},
}


def sim_dict(name="sim-sm"):
    return tomllib.loads((STATIONS / f"{name}.toml").read_text())


def error_of(data, source="stations/sim.toml") -> str:
    with pytest.raises(ConfigError) as e:
        parse_station_config(data, source)
    return str(e.value)


# -- the fixtures -------------------------------------------------------------------------
def test_example_real_parses_without_placeholders():
    c = load_station_config(STATIONS / "example-real.toml")
    assert c.robot == "agebot-sm" and c.unresolved == ()
    assert c.canopen.interface == "socketcan" and c.canopen.channel == "can0"
    assert c.canopen.nodes == (1, 2, 3, 4) and len(c.canopen.increments_per_unit) == 4
    assert c.canopen.bus_kwargs() == {"interface": "socketcan", "channel": "can0",
                                      "bitrate": 500000}
    assert c.inclinometer.port == "/dev/ttyUSB0" and c.inclinometer.baudrate == 115200
    assert c.inclinometer.axes["tilt"].raw == "pitch"
    assert c.drawwire.mode == "rtu" and c.drawwire.serial_port == "/dev/ttyUSB1"
    assert c.snapshot.noise_floor["tilt"] > 0
    assert c.require_resolved() is c


def test_example_real_names_and_comments_every_key():
    text = (STATIONS / "example-real.toml").read_text()
    for cls in (CanopenConfig, InclinometerConfig, DrawwireConfig, SnapshotConfig):
        for f in dataclasses.fields(cls):
            name = {"bus_options": "[canopen.bus]", "axes": "[inclinometer.axes]"}.get(
                f.name, f"{f.name} =")
            if f.name in ("std_limits", "drift_limits", "noise_floor"):
                name = f"[snapshot.{f.name}]"
            assert name in text, f"example-real.toml does not show {cls.__name__}.{f.name}"
    for para in re.split(r"\n\s*\n", text):
        keys = [ln for ln in para.splitlines() if re.match(r"^\s*[A-Za-z_\[]", ln)]
        if keys:
            assert "#" in para, f"uncommented block in example-real.toml: {keys}"


@pytest.mark.parametrize("name,robot,n", [("sim-sm", "agebot-sm", 4), ("sim-pm", "agebot-pm", 3)])
def test_sim_configs_parse_and_fill_from_endpoints(name, robot, n):
    c = load_station_config(STATIONS / f"{name}.toml")
    assert c.robot == robot and len(c.canopen.nodes) == n
    assert set(c.unresolved) == {"canopen.host", "canopen.port", "inclinometer.port",
                                 "drawwire.host", "drawwire.port"}
    with pytest.raises(ConfigError, match=r"sim-..\.toml: canopen\.host: '@endpoints' not filled"):
        c.require_resolved()
    ep = dict(ENDPOINTS, canopen=dict(ENDPOINTS["canopen"], nodes=list(range(1, n + 1))))
    r = with_endpoints(c, ep).require_resolved()
    assert r.canopen.bus_kwargs() == {"interface": "socketcand", "channel": "can0",
                                      "host": "127.0.0.1", "port": 29536}
    assert r.inclinometer.port == "/dev/pts/5" and r.inclinometer.baudrate == 9600
    assert (r.drawwire.host, r.drawwire.port, r.drawwire.device_id) == ("127.0.0.1", 15020, 1)
    assert r.snapshot == c.snapshot and c.unresolved  # the original is unchanged


def test_endpoints_file_and_rtu_drawwire(tmp_path):
    p = tmp_path / "ep.json"
    p.write_text('{"drawwire": {"mode": "rtu", "port": "/dev/pts/9", "baudrate": 38400},'
                 ' "control": {"port": 1}}')
    c = with_endpoints(load_station_config(STATIONS / "sim-sm.toml"), load_endpoints(p))
    assert c.drawwire.mode == "rtu" and c.drawwire.serial_port == "/dev/pts/9"
    assert c.drawwire.baudrate == 38400 and c.drawwire.port is None
    assert "drawwire.port" not in c.unresolved and "canopen.port" in c.unresolved


def test_endpoint_errors_name_the_endpoints_key():
    c = load_station_config(STATIONS / "sim-sm.toml")
    with pytest.raises(ConfigError, match=r"^ep\.json: canopen\.port: expected an integer"):
        with_endpoints(c, {"canopen": {"port": "29536"}}, source="ep.json")
    with pytest.raises(ConfigError, match=r"canopen\.nodes: expected a list of 4"):
        with_endpoints(c, {"canopen": {"nodes": [1, 2]}})
    real = load_station_config(STATIONS / "example-real.toml")
    with pytest.raises(ConfigError, match=r"^endpoints: drawwire\.port: missing required key"):
        with_endpoints(real, {"drawwire": {"host": "127.0.0.1"}})
    tcp = with_endpoints(real, {"drawwire": ENDPOINTS["drawwire"]}).drawwire
    assert (tcp.mode, tcp.host, tcp.port, tcp.serial_port) == ("tcp", "127.0.0.1", 15020, None)
    with pytest.raises(ConfigError, match="not valid JSON"):
        load_endpoints(Path(__file__))


def test_config_is_frozen():
    c = load_station_config(STATIONS / "sim-sm.toml")
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.robot = "agebot-pm"
    with pytest.raises(TypeError):
        c.snapshot.std_limits["tilt"] = 1.0
    assert isinstance(c, StationConfig)


# -- errors name the key path ------------------------------------------------------------------
def test_wrong_type_names_file_and_key():
    d = sim_dict()
    d["drawwire"]["port"] = "15020"
    assert error_of(d).startswith("stations/sim.toml: drawwire.port: expected an integer")


@pytest.mark.parametrize("mutate,expected", [
    (lambda d: d.update(colour="red"), r": colour: unknown key"),
    (lambda d: d["canopen"].update(bitrate=500000), r": canopen\.bitrate: unknown key"),
    (lambda d: d["inclinometer"]["axes"]["tilt"].update(gain=2), r"inclinometer\.axes\.tilt\.gain: unknown key"),
    (lambda d: d["canopen"].pop("nodes"), r": canopen\.nodes: missing required key"),
    (lambda d: d.pop("robot"), r": robot: missing required key"),
    (lambda d: d.pop("canopen"), r": canopen: missing required key"),
    (lambda d: d.update(robot="agebot-xx"), r": robot: 'agebot-xx' is not one of"),
    (lambda d: d["canopen"].update(nodes=[1, 2, 3]), r"canopen\.nodes: expected a list of 4"),
    (lambda d: d["canopen"].update(nodes=[1, 2, 2, 3]), r"canopen\.nodes: node ids must be distinct"),
    (lambda d: d["canopen"].update(nodes=[1, 2, 300, 3]), r"canopen\.nodes\[2\]: 300 must be <= 127"),
    (lambda d: d["canopen"]["increments_per_unit"].__setitem__(1, "x"),
     r"canopen\.increments_per_unit\[1\]: expected a finite number"),
    (lambda d: d["canopen"].update(profile_velocity=-1.0), r"canopen\.profile_velocity\[0\]: -1\.0 must be > 0"),
    (lambda d: d["canopen"].update(mode="cia401"), r"canopen\.mode: 'cia401' is not one of"),
    (lambda d: d["canopen"].update(sdo_timeout=True), r"canopen\.sdo_timeout: expected a finite number"),
    (lambda d: d["inclinometer"]["axes"].update(yawn={"raw": "yaw"}), r"inclinometer\.axes\.yawn: unknown channel"),
    (lambda d: d["inclinometer"]["axes"]["tilt"].update(sign=2), r"inclinometer\.axes\.tilt\.sign: expected 1 or -1"),
    (lambda d: d["inclinometer"]["axes"]["tilt"].update(raw="heading"), r"inclinometer\.axes\.tilt\.raw:"),
    (lambda d: d["inclinometer"].update(axes={}), r"inclinometer\.axes: map at least one channel"),
    (lambda d: d["drawwire"].update(mode="udp"), r"drawwire\.mode: 'udp' is not one of"),
    (lambda d: d["drawwire"].update(word_order="middle"), r"drawwire\.word_order:"),
    (lambda d: d["drawwire"].update(metres_per_count=0), r"drawwire\.metres_per_count: 0\.0 must be > 0"),
    (lambda d: d["drawwire"].update(mode="rtu"), r"drawwire\.serial_port: missing required key"),
    (lambda d: d["snapshot"].update(samples=2.5), r"snapshot\.samples: expected an integer"),
    (lambda d: d["snapshot"]["std_limits"].update(phi=1.0), r"snapshot\.std_limits\.phi: unknown channel"),
    (lambda d: d["snapshot"]["drift_limits"].update(tilt=-1.0), r"snapshot\.drift_limits\.tilt: -1\.0 must be >= 0"),
    (lambda d: d["snapshot"].update(std_limits=3), r"snapshot\.std_limits: expected a table"),
])
def test_errors_name_the_key_path(mutate, expected):
    d = sim_dict()
    mutate(d)
    msg = error_of(d)
    assert msg.startswith("stations/sim.toml: "), msg
    assert re.search(expected, msg), msg


def test_optional_sections_and_defaults():
    d = sim_dict("sim-pm")
    for k in ("inclinometer", "drawwire", "snapshot"):
        d.pop(k)
    c = parse_station_config(d)
    assert c.inclinometer is None and c.drawwire is None and c.snapshot == SnapshotConfig()
    assert c.canopen.heartbeat_timeout == 2.0


def test_file_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("robot = \n")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        load_station_config(bad)
    with pytest.raises(ConfigError, match=r"missing\.toml: cannot read"):
        load_station_config(tmp_path / "missing.toml")
    typo = tmp_path / "typo.toml"
    typo.write_text((STATIONS / "sim-sm.toml").read_text().replace("sync_period", "sync_periode"))
    with pytest.raises(ConfigError, match=r"typo\.toml: canopen\.sync_periode: unknown key"):
        load_station_config(typo)
