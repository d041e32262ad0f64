"""Issue 27, part A: the command line's edges. Outputs never destroy inputs or the
system, a hung device never hangs a command, a silently wrong answer is refused,
and a user's mistake is one line (``error: ...``, exit 2), never a traceback."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import pytest

import app as app_module
from drivers.sim.hung_server import HungServer

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FX = os.path.join(ROOT, "fixtures")
TRACE = os.path.join(FX, "traces", "sm-distance-tilt.jsonl")
UR5 = os.path.join(FX, "robots", "ur5-like-dh.toml")
URDF = os.path.join(FX, "robots", "m10ia-like.urdf")
TRUTH_SM = os.path.join(FX, "truth", "agebot-sm.json")
TRUTH_PM = os.path.join(FX, "truth", "agebot-pm.json")
SIM_SM = os.path.join(FX, "stations", "sim-sm.toml")


def run(capsys, *argv):
    """``app.py ARGV`` in this process: ``(rc, stdout, stderr)``."""
    try:
        rc = app_module.main([str(a) for a in argv])
    except SystemExit as e:          # argparse's own refusals
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


def app(*argv, timeout=120):
    """``python app.py ARGV`` in a subprocess (a command that could run for ever)."""
    return subprocess.run([sys.executable, os.path.join(ROOT, "app.py"), *map(str, argv)],
                          capture_output=True, text=True, cwd=ROOT, timeout=timeout)


def one_line(rc, err, *words):
    """Refused: exit 2 and one ``error: ...`` line holding every word (no traceback,
    no temporary file named)."""
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), (rc, err)
    assert ".tmp" not in lines[0], lines[0]
    for w in words:
        assert str(w) in lines[0], lines[0]
    return lines[0]


def digest(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def copy(src, folder, name=None):
    dst = os.path.join(folder, name or os.path.basename(src))
    shutil.copy(src, dst)
    return dst


def device_node(path) -> str:
    """A private character device like /dev/null (root), else a FIFO: an existing
    file that is not a regular one, which no command may replace."""
    try:
        os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except (PermissionError, OSError):
        os.mkfifo(path)
    return str(path)


def still_special(path) -> bool:
    return os.path.exists(path) and not stat.S_ISREG(os.stat(path).st_mode)


@pytest.fixture(scope="module")
def ur5_params(tmp_path_factory):
    """A parameter file of a robot file (ur5-like-dh, sm-position) and its trace."""
    d = tmp_path_factory.mktemp("ur5")
    trace, params = d / "ur5.jsonl", d / "ur5-p.json"
    assert app_module.main(["trace", "generate", "--robot", UR5, "--method", "sm-position",
                            "--out", str(trace), "--noise", "position=1e-5"]) == 0
    assert app_module.main(["batch", str(trace), "--out", str(params)]) == 0
    return str(params)


@pytest.fixture(scope="module")
def sm_params(tmp_path_factory):
    p = tmp_path_factory.mktemp("sm") / "p.json"
    assert app_module.main(["batch", TRACE, "--out", str(p)]) == 0
    return str(p)


# -- 1. outputs never destroy inputs or the system --------------------------------------
def test_trace_generate_never_writes_over_its_truth_file(tmp_path, capsys):
    truth = copy(TRUTH_SM, tmp_path)
    before = digest(truth)
    one_line(*run(capsys, "trace", "generate", "--method", "sm-distance", "--truth", truth,
                  "--out", truth)[::2], "is the input")
    assert digest(truth) == before


def test_trace_generate_never_writes_over_its_robot_file(tmp_path, capsys):
    robot = copy(UR5, tmp_path)
    before = digest(robot)
    one_line(*run(capsys, "trace", "generate", "--robot", robot, "--method", "sm-position",
                  "--out", robot)[::2], "the trace", "is the input")
    assert digest(robot) == before
    truth = str(tmp_path / "t.json")         # a truth file that is also the output
    one_line(*run(capsys, "trace", "generate", "--robot", robot, "--method", "sm-position",
                  "--truth", truth, "--out", truth)[::2], "is the input")
    assert sorted(os.listdir(tmp_path)) == ["ur5-like-dh.toml"]


def test_trace_generate_never_writes_over_its_urdf(tmp_path, capsys):
    urdf = copy(URDF, tmp_path)
    before = digest(urdf)
    one_line(*run(capsys, "trace", "generate", "--robot", urdf, "--base-link", "base_link",
                  "--tip-link", "flange", "--method", "sm-markers", "--out", urdf)[::2],
             "is the input")
    assert digest(urdf) == before


@pytest.mark.parametrize("flag", ["--urdf", "--robot-file"])
def test_params_export_never_writes_over_the_parameter_file(tmp_path, capsys, ur5_params, flag):
    p = copy(ur5_params, tmp_path)
    before = digest(p)
    one_line(*run(capsys, "params", "export", p, flag, p)[::2], "is the input")
    assert digest(p) == before


def test_params_export_refuses_one_path_for_both_outputs(tmp_path, capsys, ur5_params):
    out = tmp_path / "x.out"
    one_line(*run(capsys, "params", "export", ur5_params, "--urdf", out, "--robot-file",
                  out)[::2], "is also the URDF")
    assert not out.exists()


def test_params_export_writes_nothing_when_one_output_cannot_be_written(tmp_path, capsys,
                                                                         ur5_params):
    """``--robot-file`` into a missing folder: the URDF is not written either, and the
    message names the output the user gave, never the writer's temporary file."""
    line = one_line(*run(capsys, "params", "export", ur5_params, "--urdf", tmp_path / "a.urdf",
                         "--robot-file", tmp_path / "nope" / "b.toml")[::2],
                    "robot file", "does not exist")
    assert "b.toml" in line
    assert os.listdir(tmp_path) == []


def test_a_failed_write_names_the_output_not_the_temporary_file(tmp_path, monkeypatch):
    from drivers import atomic

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied", src, None, dst)

    monkeypatch.setattr(atomic.os, "replace", refuse)
    with pytest.raises(OSError) as e:
        atomic.write_atomic(tmp_path / "p.json", b"{}")
    assert e.value.filename == str(tmp_path / "p.json")
    assert os.listdir(tmp_path) == []


def test_write_atomic_never_replaces_a_device(tmp_path):
    from drivers.atomic import write_atomic

    node = device_node(tmp_path / "null")
    with pytest.raises(OSError, match="not a regular file"):
        write_atomic(node, b"x")
    assert still_special(node) and os.listdir(tmp_path) == ["null"]


@pytest.mark.parametrize("command", [
    lambda out: ["batch", TRACE, "--out", out],
    lambda out: ["batch", TRACE, "--out", os.path.join(os.path.dirname(out), "p.json"),
                 "--report", out],
    lambda out: ["trace", "generate", "--method", "sm-distance", "--out", out],
    lambda out: ["trace", "generate", "--robot", UR5, "--method", "sm-position", "--out", out],
], ids=["batch", "batch-report", "generate", "generate-robot-file"])
def test_an_output_that_is_a_device_is_refused(tmp_path, capsys, command):
    """``--out /dev/null`` (a private device node like it, or a FIFO): refused before
    any work; the node stays a device (the atomic writer would rename a file over it)."""
    node = device_node(tmp_path / "dev")
    one_line(*run(capsys, *command(node))[::2], "not a regular file")
    assert still_special(node) and os.listdir(tmp_path) == ["dev"]


def test_params_export_to_a_device_is_refused(tmp_path, capsys, ur5_params):
    node = device_node(tmp_path / "dev")
    one_line(*run(capsys, "params", "export", ur5_params, "--urdf", node)[::2],
             "not a regular file")
    assert still_special(node)


def test_batch_out_empty_is_refused_before_the_fit(capsys, monkeypatch):
    import station.fitting.batch

    def no_fit(*a, **k):
        raise AssertionError("fitted before the output was checked")

    monkeypatch.setattr(station.fitting.batch, "calibrate_trace", no_fit)
    one_line(*run(capsys, "batch", TRACE, "--out", "")[::2], "parameter file", "empty")


def test_simulate_never_writes_its_endpoints_over_an_input(tmp_path):
    truth, cfg = copy(TRUTH_SM, tmp_path), copy(SIM_SM, tmp_path)
    node = device_node(tmp_path / "dev")
    sums = (digest(truth), digest(cfg))
    for args, word in ((["--truth", truth, "--endpoints", truth], "is the input"),
                       (["--config", cfg, "--endpoints", cfg], "is the input"),
                       (["--endpoints", node], "not a regular file")):
        r = app("simulate", "--robot", "agebot-sm", *args, timeout=60)
        one_line(r.returncode, r.stderr, "--endpoints", word)
    assert (digest(truth), digest(cfg)) == sums and still_special(node)


def test_run_out_that_is_an_input_or_a_device(tmp_path, capsys):
    robot, truth = copy(UR5, tmp_path), copy(TRUTH_SM, tmp_path)
    sums = digest(robot), digest(truth)
    node = device_node(tmp_path / "dev")
    one_line(*run(capsys, "run", "--simulate", "--robot", "agebot-sm", "--truth", truth,
                  "--method", "sm-distance", "--out", truth)[::2], "is the input")
    one_line(*run(capsys, "run", "--simulate", "--robot", robot, "--truth", truth,
                  "--method", "sm-position", "--out", robot)[::2], "is the input")
    one_line(*run(capsys, "run", "--simulate", "--robot", "agebot-sm", "--method",
                  "sm-distance", "--out", node)[::2], "not a folder")
    one_line(*run(capsys, "run", "--simulate", "--robot", "agebot-sm", "--method",
                  "sm-distance", "--out", "")[::2], "empty")
    assert (digest(robot), digest(truth)) == sums and still_special(node)


def test_study_output_folder_files_are_checked(tmp_path, capsys):
    folder = tmp_path / "study"
    folder.mkdir()
    node = device_node(folder / "summary.json")
    one_line(*run(capsys, "study", "--method", "sm-distance", "--robots", "1", "--out",
                  folder)[::2], "summary.json", "not a regular file")
    assert still_special(node)


# -- 2. hangs -----------------------------------------------------------------------------
@pytest.fixture
def hung_config(tmp_path):
    """The simulated SM station with its CAN bus on a hung socketcand server and the
    other devices on a closed port."""
    hung = HungServer()
    dead = socket.socket()
    dead.bind(("127.0.0.1", 0))
    dead_port = dead.getsockname()[1]
    dead.close()
    text = open(SIM_SM).read()
    text = text.replace('host = "@endpoints"\nport = "@endpoints"\nnodes',
                        f'host = "127.0.0.1"\nport = {hung.port}\nnodes', 1)
    text = text.replace('port = "@endpoints"\nbaudrate',
                        f'port = "socket://127.0.0.1:{dead_port}"\nbaudrate')
    text = text.replace('host = "@endpoints"\nport = "@endpoints"',
                        f'host = "127.0.0.1"\nport = {dead_port}')
    cfg = tmp_path / "hung.toml"
    cfg.write_text(text)
    yield str(cfg), hung.port
    hung.close()


def test_devices_check_against_a_hung_socketcand_names_the_bus(hung_config, capsys):
    cfg, port = hung_config
    t0 = time.monotonic()
    rc, out, err = run(capsys, "devices", "check", "--config", cfg, "--seconds", "0.2")
    assert time.monotonic() - t0 < 60
    one_line(rc, err, "canopen", "did not answer")
    assert f"CAN bus socketcand can0 at 127.0.0.1:{port}" in out and "greeting" in out, out


def test_run_against_a_hung_socketcand_is_one_line_naming_the_bus(hung_config, tmp_path,
                                                                  capsys):
    cfg, port = hung_config
    rc, out, err = run(capsys, "run", "--config", cfg, "--robot", "agebot-sm", "--method",
                       "sm-distance-tilt", "--out", tmp_path / "run")
    one_line(rc, err, f"CAN bus socketcand can0 at 127.0.0.1:{port}", "greeting")


def test_a_bus_that_never_comes_up_is_a_timeout(monkeypatch):
    """python-can's connect has no timeout of its own: the station bounds it."""
    import canopen

    from drivers import canopen_bus, canopen_nodes
    from drivers.errors import DeviceTimeout

    gate = threading.Event()
    monkeypatch.setattr(canopen_bus, "CONNECT_TIMEOUT_S", 0.3)
    monkeypatch.setattr(canopen.Network, "connect", lambda self, **kw: gate.wait(30))
    nodes = canopen_nodes.CanopenNodes([1], 1.0, interface="virtual", channel="x",
                                       timeout=0.1)
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeout, match="CAN bus virtual x: no connection within"):
        nodes._open_internal()
    assert time.monotonic() - t0 < 5
    gate.set()


@pytest.mark.parametrize("args, words", [
    (["study", "--method", "sm-distance", "--robots", "1", "--workers", "-1"], ["--workers"]),
    (["study", "--method", "sm-distance", "--robots", "1", "--workers", "0"], ["--workers"]),
    (["devices", "check", "--config", SIM_SM, "--seconds", "nan"], ["--seconds"]),
    (["devices", "check", "--config", SIM_SM, "--seconds", "inf"], ["--seconds"]),
    (["devices", "check", "--config", SIM_SM, "--seconds", "-1"], ["--seconds"]),
], ids=["workers-1", "workers0", "seconds-nan", "seconds-inf", "seconds-neg"])
def test_options_that_would_run_for_ever_are_refused(tmp_path, args, words):
    r = app(*args, "--out", tmp_path / "s", timeout=60) if args[0] == "study" \
        else app(*args, timeout=60)
    one_line(r.returncode, r.stderr, *words)


# -- 3. silently wrong ----------------------------------------------------------------------
@pytest.mark.parametrize("robot, method", [("agebot-pm", "sm-distance"),
                                           ("agebot-sm", "pm-fk")])
def test_trace_generate_refuses_a_built_in_robot_that_is_not_the_method_s(tmp_path, capsys,
                                                                          robot, method):
    one_line(*run(capsys, "trace", "generate", "--robot", robot, "--method", method, "--out",
                  tmp_path / "t.jsonl")[::2], robot, method)
    assert os.listdir(tmp_path) == []


def _resigned(doc, tmp_path, name="p.json", text=None):
    from station.outputs.params_file import checksum

    doc = json.loads(json.dumps(doc))
    doc["checksum"] = checksum(doc)
    p = tmp_path / name
    p.write_text(text(doc) if text else json.dumps(doc))
    return p


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["parameters"]["L2"].update(value=-5.0), ["parameters.L2", "plausible"]),
    (lambda d: d["parameters"]["L2"].update(value=1e308), ["parameters.L2", "plausible"]),
    (lambda d: d["parameters"]["k1"].update(value=0.0), ["parameters.k1", "plausible"]),
    (lambda d: d["fit"]["quality"].update(passed=False), ["fit.quality", "not accepted"]),
    (lambda d: d["parameters"]["theta0"].update(value=1e12), ["parameters.theta0", "1000"]),
], ids=["L2-negative", "L2-1e308", "k1-zero", "quality-failed", "theta0-huge"])
def test_params_verify_judges_values_and_fit_quality(tmp_path, capsys, sm_params, edit,
                                                     words):
    doc = json.load(open(sm_params))
    edit(doc)
    one_line(*run(capsys, "params", "verify", _resigned(doc, tmp_path))[::2], *words)


def test_params_verify_refuses_a_robot_file_s_fixed_ratio_changed(tmp_path, capsys,
                                                                   ur5_params):
    doc = json.load(open(ur5_params))
    assert not doc["parameters"]["k1"]["identifiable"]          # held by the robot file
    doc["parameters"]["k1"]["value"] = 0.0
    p = _resigned(doc, tmp_path)
    one_line(*run(capsys, "params", "verify", p)[::2], "parameters.k1", "did not calibrate")
    one_line(*run(capsys, "params", "export", p, "--robot-file", tmp_path / "o.toml")[::2],
             "parameters.k1")
    assert not (tmp_path / "o.toml").exists()


def test_params_verify_refuses_a_duplicated_key(tmp_path, capsys, sm_params):
    doc = json.load(open(sm_params))
    p = _resigned(doc, tmp_path, text=lambda d: json.dumps(d).replace(
        '"value": ', '"value": -5.0, "value": ', 1))
    one_line(*run(capsys, "params", "verify", p)[::2], "value", "twice")


def test_params_verify_passes_a_poor_fit_accepted_on_purpose(tmp_path, capsys, sm_params):
    doc = json.load(open(sm_params))
    doc["fit"]["quality"].update(passed=False, accepted=True)
    rc, out, err = run(capsys, "params", "verify", _resigned(doc, tmp_path))
    assert rc == 0 and "poor fit accepted" in out, err


def test_a_number_beyond_a_double_in_a_parameter_file_is_one_line(tmp_path, capsys,
                                                                  ur5_params):
    doc = json.load(open(ur5_params))
    p = _resigned(doc, tmp_path, text=lambda d: json.dumps(d).replace(
        '"value": ', '"value": 1e400, "x": ', 1))
    one_line(*run(capsys, "params", "export", p, "--robot-file", tmp_path / "o.toml")[::2],
             "out of range")
    one_line(*run(capsys, "params", "verify", p)[::2], "out of range")


@pytest.mark.parametrize("key, value", [
    ("drop_prob", "lots"), ("drop_prob", -0.1), ("drop_prob", 2), ("drop_prob", None),
    ("corrupt_prob", float("nan")), ("late_s", "slow"), ("late_s", -1), ("late_s", 1e300),
    ("silent_nodes", "abc"), ("silent_nodes", [999]), ("silent_nodes", 5),
    ("drive_fault_node", "x"), ("drive_fault_node", 1.5), ("modbus_exception", 999),
    ("inclinometer_silent", "maybe"), ("inclinometer_lag_s", -1), ("drawwire_down", 2),
    ("drawwire_unanswered", -1)])
def test_every_fault_value_is_checked_and_the_plan_left_as_it_was(key, value):
    from drivers.sim.faults import FaultPlan

    plan = FaultPlan()
    before = plan.as_dict()
    with pytest.raises(ValueError, match=key):
        plan.update(drop_prob=0.5, **{key: value}) if key != "drop_prob" \
            else plan.update(late_s=0.5, **{key: value})
    assert plan.as_dict() == before


def test_the_simulated_inclinometer_outlives_a_bad_value():
    """A value that reaches the sensor's thread anyway (set behind the plan's back)
    costs a frame, never the thread: it talks again once the value is gone."""
    from drivers.sim.faults import FaultPlan
    from drivers.sim.inclinometer_sim import SimInclinometer

    plan = FaultPlan()
    with SimInclinometer(lambda: (0.0, 0.0, 0.0), rate_hz=100, faults=plan) as sim:
        time.sleep(0.1)
        plan.drop_prob = "lots"
        time.sleep(0.2)
        plan.drop_prob = 0.0
        sent = sim.frames_sent
        time.sleep(0.3)
        assert sim.frames_sent > sent


def test_the_control_port_answers_an_error_naming_the_key_and_devices_live_on():
    from drivers.check import check
    from drivers.sim.server import SimulatorProcess

    with SimulatorProcess("agebot-sm") as sim, sim.control() as ctl:
        with pytest.raises(RuntimeError, match="drop_prob"):
            ctl.call(faults={"drop_prob": "lots"})
        with pytest.raises(RuntimeError, match="move"):
            ctl.call(move=["nan", 0, 0, 0])
        assert ctl.call(state=True)["faults"]["drop_prob"] == 0.0
        time.sleep(0.3)
        ctl.call(clear=True)
        assert check(sim.station_config(), 0.3, out=open(os.devnull, "w"))


# -- 4. a user's mistake is one line ----------------------------------------------------
GEN = ["trace", "generate", "--method", "sm-distance"]
RUN = ["run", "--simulate", "--robot", "agebot-sm", "--method", "sm-distance-tilt"]
STUDY = ["study", "--method", "sm-distance", "--robots", "1"]


@pytest.mark.parametrize("argv, words", [
    *[(GEN + ["--noise", f"distance={v}"], ["--noise", "distance"])
      for v in ("nan", "inf", "-1", "0")],
    (GEN + ["--noise", "bogus=1e-4"], ["unknown channel 'bogus'"]),
    (["trace", "generate", "--robot", UR5, "--method", "sm-position", "--noise",
      "position=nan"], ["--noise", "position"]),
    (["trace", "generate", "--robot", UR5, "--method", "sm-position", "--noise",
      "position=0"], ["--noise", "position"]),
    (GEN + ["--seed", "-1"], ["--seed -1"]),
    (GEN + ["--count", "-5"], ["--count -5"]),
    (GEN + ["--count", "0"], ["--count 0"]),
    (["trace", "generate", "--robot", UR5, "--method", "sm-position", "--count", "-5"],
     ["--count -5"]),
    (["trace", "generate", "--method", "pm-fk", "--components", "alpha,delta"],
     ["--components", "alpha,delta"]),
    (["trace", "generate", "--method", "pm-fk", "--components", ","], ["--components"]),
    (GEN + ["--components", "alpha"], ["--components", "pm-fk"]),
    (RUN + ["--count", "-5"], ["--count -5"]),
    (RUN + ["--count", "0"], ["--count 0"]),
    (RUN + ["--seed", "-1"], ["--seed -1"]),
    (RUN + ["--sim-seed", "-1"], ["--sim-seed -1"]),
    (["run", "--simulate", "--robot", "agebot-sm", "--method", "bogus"], ["--method", "bogus"]),
    (["simulate", "--robot", "agebot-sm", "--seed", "-1"], ["--seed -1"]),
    (STUDY + ["--seed", "-1"], ["--seed -1"]),
    (STUDY + ["--scheduler", "foo"], ["--scheduler", "tcp://HOST:PORT"]),
    (STUDY + ["--count", "-1"], ["--count -1"]),
    (STUDY + ["--noise", "distance=nan"], ["--noise"]),
    (STUDY + ["--noise", "bogus=1"], ["unknown channel"]),
    (["batch", TRACE, "--max-iter", "-5"], ["--max-iter -5"]),
    (["batch", TRACE, "--bogus"], ["unrecognized arguments: --bogus"]),
], ids=lambda v: " ".join(map(str, v))[-40:] if isinstance(v, list) else None)
def test_a_bad_argument_is_one_line(tmp_path, capsys, argv, words):
    out = ["--out", tmp_path / ("o.json" if argv[0] == "batch" else "o")]
    if argv[0] == "simulate":
        out = []
    one_line(*run(capsys, *argv, *out)[::2], *words)
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.json").exists()


def test_a_truth_file_of_the_other_robot_is_one_line(tmp_path, capsys):
    one_line(*run(capsys, *RUN, "--truth", TRUTH_PM, "--out", tmp_path / "o")[::2],
             "agebot-pm", "agebot-sm")


def _robot(tmp_path, edit, name="r.toml"):
    text = open(UR5, encoding="utf-8").read()
    data = edit(text)
    p = tmp_path / name
    p.write_bytes(data if isinstance(data, bytes) else data.encode("utf-8"))
    return p


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("limits = [", "limits = [-1e308, 1e308]\n#", 1), ["joint[1].limits"]),
    (lambda t: t.replace("k = ", "k = 1e308\n#", 1), ["joint[1].k"]),
    (lambda t: t.replace("\na = ", "\na = 1e308\n#", 1), [".a: 1e+308 must be <= 1000"]),
    (lambda t: t + "\nx = " + "[" * 100000 + "]" * 100000 + "\n", ["nested too deeply"]),
    (lambda t: t.replace('name = "', 'name = "a\\nb', 1), ["name", "one line"]),
], ids=["limits-1e308", "k-1e308", "a-1e308", "nested", "name-newline"])
def test_a_robot_file_beyond_reason_is_one_line(tmp_path, capsys, edit, words):
    robot = _robot(tmp_path, edit)
    one_line(*run(capsys, "trace", "generate", "--robot", robot, "--method", "sm-position",
                  "--out", tmp_path / "t.jsonl")[::2], "r.toml", *words)


def test_a_robot_file_with_a_bom_reads(tmp_path, capsys):
    robot = _robot(tmp_path, lambda t: b"\xef\xbb\xbf" + t.encode("utf-8"))
    rc, out, err = run(capsys, "trace", "generate", "--robot", robot, "--method",
                       "sm-position", "--out", tmp_path / "t.jsonl")
    assert rc == 0, err


def test_a_station_config_nested_too_deeply_is_one_line(tmp_path, capsys):
    cfg = tmp_path / "st.toml"
    cfg.write_text(open(SIM_SM).read() + "\nx = " + "[" * 100000 + "]" * 100000 + "\n")
    one_line(*run(capsys, "devices", "check", "--config", cfg, "--seconds", "0.1")[::2],
             "st.toml", "nested too deeply")


def test_an_exported_robot_file_reads_back_whatever_its_name(tmp_path):
    """Names with quotes, backslashes and non-ASCII go into the calibrated robot file
    escaped, and read back the same."""
    import dataclasses

    from calibration.robots import get_robot
    from drivers.robot_file import load_robot_file, parse_robot_file
    from station.outputs.export import robot_file_text

    spec = load_robot_file(UR5)
    for name in ('a"b', "a\\b", "ä ö 😀", "x'y"):
        robot = get_robot(dataclasses.replace(spec, name=name))
        text = robot_file_text(robot, robot.nominal)
        assert parse_robot_file(text, "out.toml").name == name


def test_params_export_of_a_robot_named_over_two_lines_is_one_line(tmp_path, capsys,
                                                                  ur5_params):
    """A parameter file whose robot file's name holds a newline (written before the
    reader refused such names): the export refuses it in one line, writes nothing."""
    doc = json.load(open(ur5_params))
    src = doc["robot_file"]
    text = src["text"].replace('name = "ur5-like-dh"', 'name = "ur5\\nlike"')
    src.update(text=text, sha256=hashlib.sha256(text.encode()).hexdigest())
    p = _resigned(doc, tmp_path)
    one_line(*run(capsys, "params", "export", p, "--robot-file", tmp_path / "o.toml")[::2],
             "name", "one line")
    assert not (tmp_path / "o.toml").exists()


def test_a_study_summary_has_no_nan(tmp_path):
    """No calibration succeeded: the summary's figures are null, never NaN (which
    JSON has not)."""
    from station.simulation.study import _json_safe, summarize

    doc = _json_safe(summarize([{"design": "random", "ok": False, "error": "x",
                                 "index": 0}], ("random",)))
    text = json.dumps(doc, allow_nan=False)
    assert json.loads(text)["random"]["rms_z"] is None


# -- 5. the retry window --------------------------------------------------------------------
def test_the_retry_window_is_a_station_config_setting(tmp_path):
    from calibration.errors import ConfigError
    from drivers.config import load_station_config

    assert load_station_config(SIM_SM).session.retry_window == 0.0
    cfg = tmp_path / "st.toml"
    cfg.write_text(open(SIM_SM).read() + "\n[session]\nretry_window = 30.0\n")
    assert load_station_config(cfg).session.retry_window == 30.0
    for bad in ("-1.0", "nan", "1e9", '"long"'):
        cfg.write_text(open(SIM_SM).read() + f"\n[session]\nretry_window = {bad}\n")
        with pytest.raises(ConfigError, match="session.retry_window"):
            load_station_config(cfg)


def test_the_headless_policy_retries_within_the_window(monkeypatch):
    from station.session import retries

    now = [100.0]
    monkeypatch.setattr(retries.time, "monotonic", lambda: now[0])
    pose = SimpleNamespace(index=4)
    plain = retries.retry_then_skip()
    assert [plain(pose, None, a) for a in range(5)] == ["retry"] * 3 + ["skip"] * 2
    windowed = retries.retry_then_skip(window=10.0)
    assert windowed(pose, None, 0) == "retry"
    now[0] += 9.0
    assert windowed(pose, None, 7) == "retry"          # 9 s into the window
    now[0] += 2.0
    assert windowed(pose, None, 8) == "skip"           # 11 s: the window is spent


def test_a_session_folder_holding_a_device_is_refused_for_the_wizard_too(tmp_path):
    """The wizard opens its sessions through :class:`station.session.session.Session`, which
    checks the folder as ``run --out`` does: a ``params.json`` there that is a device
    is refused before the session starts."""
    from calibration.errors import ConfigError
    from drivers.config import load_station_config
    from station.session.session import Session

    folder = tmp_path / "session"
    folder.mkdir()
    node = device_node(folder / "params.json")
    with pytest.raises(ConfigError, match="params.json.*not a regular file"):
        Session(load_station_config(SIM_SM), "sm-distance-tilt", folder)
    assert still_special(node) and sorted(os.listdir(folder)) == ["params.json"]


@pytest.mark.parametrize("key, value", [("sdo_timeout", "1e308"), ("move_timeout", "1e308"),
                                        ("heartbeat_timeout", "1e308"),
                                        ("samples", "100000000000")])
def test_a_station_config_timeout_beyond_reason_is_refused(tmp_path, key, value):
    """A timeout of 1e308 s would hang a command as good as for ever."""
    import re

    from calibration.errors import ConfigError
    from drivers.config import load_station_config

    cfg = tmp_path / "st.toml"
    cfg.write_text(re.sub(rf"^{key} = .*$", f"{key} = {value}", open(SIM_SM).read(), count=1,
                          flags=re.M))
    with pytest.raises(ConfigError, match=rf"{key}: .* must be <="):
        load_station_config(cfg)


def test_run_refuses_a_config_of_another_robot(tmp_path, capsys):
    """``run --config`` of an AGEBOT arm's station with ``--robot agebot-pm`` ran the arm's
    session without a word; now one line, before any device is touched."""
    from tests.simconfig import quick_config

    cfg = quick_config(tmp_path / "station", "agebot-sm")
    rc, out, err = run(capsys, "run", "--config", cfg, "--robot", "agebot-pm", "--method",
                       "pm-fk", "--out", tmp_path / "s")
    one_line(rc, err, "is for agebot-sm, not agebot-pm", "--robot")
    assert not (tmp_path / "s").exists()
