"""A URDF robot named at the station's edge: --robot FILE.urdf with its chain, the station
config's robot_file, the URDF truth file, the commands' one-line refusals."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from calibration.errors import ConfigError
from drivers.config import parse_station_config
from drivers.robot_file import load_robot_file, robot_args, robot_ref, split_urdf_ref, urdf_ref
from drivers.sim.truth import load_truth

ROOT = Path(__file__).resolve().parents[2]
URDF = ROOT / "fixtures" / "robots" / "m10ia-like.urdf"
TOML = ROOT / "fixtures" / "robots" / "ur5-like-dh.toml"


def _app(*args, cwd=None):
    return subprocess.run([sys.executable, str(ROOT / "app.py"), *map(str, args)],
                          capture_output=True, text=True, timeout=120, cwd=cwd)


def test_a_urdf_robot_is_named_with_its_chain():
    ref = robot_ref(str(URDF), "base_link", "tool0")
    assert split_urdf_ref(ref) == (str(URDF), "base_link", "tool0")
    assert robot_args(ref) == ["--robot", str(URDF), "--base-link", "base_link",
                               "--tip-link", "tool0"]
    spec = load_robot_file(ref)
    assert (spec.base_link, spec.tip_link) == ("base_link", "tool0")
    assert robot_ref(ref) == ref                      # named already: as it is
    assert robot_ref("agebot-sm") == "agebot-sm"
    with pytest.raises(ConfigError, match="needs --base-link and --tip-link"):
        robot_ref(str(URDF), "base_link", None)
    with pytest.raises(ConfigError, match="not a URDF"):
        robot_ref(str(TOML), "base_link", "tool0")
    with pytest.raises(ConfigError, match="needs --base-link and --tip-link"):
        load_robot_file(str(URDF))
    with pytest.raises(ConfigError, match="no_such_link"):
        load_robot_file(urdf_ref(URDF, "base_link", "no_such_link"))


def _station(**top) -> dict:
    from drivers.sim.serial_robot import sim_config_data

    data = sim_config_data(load_robot_file(urdf_ref(URDF, "base_link", "tool0")))
    del data["robot"]
    return {**top, **data}


def test_a_station_config_names_a_urdf_robot(tmp_path):
    src = str(ROOT / "fixtures" / "robots" / "station.toml")   # paths relative to its folder
    c = parse_station_config(_station(robot_file="m10ia-like.urdf", base_link="base_link",
                                      tip_link="tool0"), src)
    assert c.spec.tip_link == "tool0" and len(c.spec.joints) == 6
    with pytest.raises(ConfigError, match="tip_link: missing required key"):
        parse_station_config(_station(robot_file="m10ia-like.urdf", base_link="base_link"), src)
    with pytest.raises(ConfigError, match="base_link: chooses the chain of a URDF robot"):
        parse_station_config(_station(robot_file="ur5-like-dh.toml", base_link="base_link"), src)


def test_truth_draw_of_a_urdf_robot_and_its_refusals(tmp_path):
    r = _app("truth", "draw", "--robot", URDF, "--base-link", "base_link", "--tip-link",
             "tool0", "--seed", 3, "--out", tmp_path / "t.json")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "t-true.urdf").is_file() and "t-true.urdf" in r.stdout
    t = load_truth(tmp_path / "t.json")
    assert t.robot == "urdf" and len(t.points) == 3 and t.spec.tip_link == "tool0"
    data = json.loads((tmp_path / "t.json").read_text())
    assert set(data) >= {"urdf", "base_link", "tip_link", "measurement_frame", "points_on_tool"}
    # the truth's robot is the URDF as built: another chain is refused in one line
    bad = dict(data, tip_link="link_6")
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    r = _app("run", "--simulate", "--robot", URDF, "--base-link", "base_link", "--tip-link",
             "tool0", "--method", "sm-markers", "--truth", tmp_path / "bad.json",
             "--out", tmp_path / "D")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "not of the URDF robot" in r.stderr and "link_6" in r.stderr, r.stderr
    (tmp_path / "bad2.json").write_text(json.dumps(dict(data, points_on_tool=[])))
    with pytest.raises(ConfigError, match="points_on_tool"):
        load_truth(tmp_path / "bad2.json")
    (tmp_path / "bad3.json").write_text(json.dumps(dict(data, colour="red")))
    with pytest.raises(ConfigError, match="colour: unknown key"):
        load_truth(tmp_path / "bad3.json")
    # no truth: a simulated URDF robot needs one (what it really is, where the room is)
    r = _app("run", "--simulate", "--robot", URDF, "--base-link", "base_link", "--tip-link",
             "tool0", "--method", "sm-markers", "--out", tmp_path / "E")
    assert r.returncode == 2 and "needs --truth" in r.stderr and len(r.stderr.splitlines()) == 1
    assert not (tmp_path / "D").exists() and not (tmp_path / "E").exists()
    # a chain given with a robot that is not a URDF
    r = _app("run", "--simulate", "--robot", TOML, "--base-link", "b", "--method",
             "sm-distance", "--out", tmp_path / "F")
    assert r.returncode == 2 and "not a URDF" in r.stderr, r.stderr


def test_devices_check_shows_the_motion_capture_live(tmp_path):
    r = _app("truth", "draw", "--robot", URDF, "--base-link", "base_link", "--tip-link",
             "tool0", "--seed", 4, "--out", tmp_path / "t.json")
    assert r.returncode == 0, r.stderr
    r = _app("devices", "check", "--simulate", "--robot", URDF, "--base-link", "base_link",
             "--tip-link", "tool0", "--truth", tmp_path / "t.json", "--seconds", "0.5")
    assert r.returncode == 0, r.stderr
    assert "OK    motion capture" in r.stdout and "tool1" in r.stdout, r.stdout


def test_sm_markers_needs_a_urdf_robot_and_a_motion_capture(tmp_path):
    from drivers.sim.serial_robot import sim_config
    from station.session.session import Session

    config = sim_config(str(TOML))
    with pytest.raises(ConfigError, match="calibrates a URDF robot"):
        Session(config, "sm-markers", tmp_path / "s")
    config = sim_config(urdf_ref(URDF, "base_link", "tool0"))       # no truth: no [mocap]
    with pytest.raises(ConfigError, match=r"no \[mocap\] section"):
        Session(config, "sm-markers", tmp_path / "s")
    assert not (tmp_path / "s").exists()
