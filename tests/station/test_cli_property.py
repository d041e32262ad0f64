"""Property-based tests (hypothesis) of the command line and the TOML readers (issue
27): whatever the arguments, ``app.py`` exits 0 or 2 with one ``error: ...`` line,
never a traceback, never changes an input file or a device node, in bounded time;
any robot file or station config text reads or is one ConfigError line.

The commands run in this process. What would run for long after the edge checks
(a session, the simulator's devices, a Dask study, live readings) is replaced by a
stub that ends the command as accepted: these tests are about the edge. The
default suite runs few examples; ``-m slow`` runs many more."""
from __future__ import annotations

import hashlib
import os
import shutil
import stat
import sys
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import app as app_module
from calibration.errors import ConfigError

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
FX = os.path.join(ROOT, "fixtures")

QUICK = settings(max_examples=25, deadline=None, derandomize=True,
                 suppress_health_check=list(HealthCheck))
MANY = settings(max_examples=400, deadline=None, derandomize=True,
                suppress_health_check=list(HealthCheck))


class Accepted(Exception):
    """A stub reached: the command passed its edge checks."""


def _accept(*a, **k):
    raise Accepted


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """Copies of the inputs, a parameter file of a robot file, a CSV, a device node."""
    d = tmp_path_factory.mktemp("cli-prop")
    files = {}
    for src, name in (("traces/sm-distance.jsonl", "t.jsonl"), ("robots/ur5-like-dh.toml",
                                                               "ur5.toml"),
                      ("robots/m10ia-like.urdf", "m10.urdf"), ("truth/agebot-sm.json",
                                                              "truth.json"),
                      ("truth/agebot-pm.json", "truth-pm.json"),
                      ("stations/sim-sm.toml", "st.toml")):
        shutil.copy(os.path.join(FX, src), d / name)
        files[name] = str(d / name)
    trace = d / "ur5.jsonl"
    assert app_module.main(["trace", "generate", "--robot", files["ur5.toml"], "--method",
                            "sm-position", "--out", str(trace), "--count", "40",
                            "--noise", "position=1e-5"]) == 0
    files["ur5.jsonl"] = str(trace)
    assert app_module.main(["batch", str(trace), "--out", str(d / "ur5-p.json")]) == 0
    files["ur5-p.json"] = str(d / "ur5-p.json")
    import json

    rows = [json.loads(x) for x in open(trace)]
    with open(d / "ur5.csv", "w") as f:
        f.write("qm1,qm2,qm3,qm4,qm5,qm6,x,y,z\n")
        for r in rows:
            if r.get("record") == "pose":
                f.write(",".join(repr(v) for v in r["qm"] + r["position"]) + "\n")
    files["ur5.csv"] = str(d / "ur5.csv")
    node = d / "dev"
    try:
        os.mknod(node, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
    except OSError:
        os.mkfifo(node)
    (d / "out").mkdir()
    return d, files, str(node)


def _digests(files):
    return {k: hashlib.sha256(open(p, "rb").read()).hexdigest() for k, p in files.items()}


def _stub_long_work(monkeypatch):
    import drivers.check
    import drivers.sim.server
    import station.headless
    import station.simulation.study

    monkeypatch.setattr(drivers.sim.server, "SimulatorProcess", _accept)
    monkeypatch.setattr(drivers.sim.server.SimStation, "start", _accept)
    monkeypatch.setattr(station.headless, "_run", _accept)
    monkeypatch.setattr(station.simulation.study, "run_study", _accept)
    monkeypatch.setattr(drivers.check, "check", _accept)


# -- argument strategies ---------------------------------------------------------------------
NUMBERS = st.sampled_from(["-1", "0", "1", "3", "12", "nan", "inf", "-inf", "1e308", "-5",
                           "abc", "", "1e3", "0.5", "99999999999999999999999", "2"])
METHODS = st.sampled_from(["sm-distance", "sm-distance-tilt", "sm-position", "pm-fk",
                           "pm-tilt", "sm-markers", "sm-plane", "bogus", ""])
NOISE = st.builds(lambda k, v: f"{k}={v}", st.sampled_from(
    ["distance", "tilt", "position", "orientation", "roll", "bogus", ""]), NUMBERS) \
    | st.sampled_from(["distance", "=1", "distance==1"])


def paths(files, node, out):
    """Any file name a user could give: inputs, the device, new files, odd names."""
    return st.sampled_from(list(files.values()) + [
        node, "", ".", out, os.path.join(out, "new.json"), os.path.join(out, "new.jsonl"),
        os.path.join(out, "nope", "x.json"), "/proc/x.json", os.path.join(out, "new.toml"),
        os.path.join(out, "run"), "agebot-sm", "agebot-pm"])


def argv_strategy(files, node, out):
    P = paths(files, node, out)
    robots = st.sampled_from(["agebot-sm", "agebot-pm", files["ur5.toml"], files["m10.urdf"],
                              files["truth.json"], "nope.toml", ""])
    opts = {
        "batch": lambda: st.tuples(st.just(["batch"]), st.lists(P, min_size=1, max_size=1),
                                   st.lists(st.sampled_from([
                                       ("--out", P), ("--report", P), ("--method", METHODS),
                                       ("--max-iter", NUMBERS), ("--exclude", NUMBERS),
                                       ("--exclude-reason", st.just("r")),
                                       ("--hold", st.sampled_from(["k*", "zz", ""])),
                                       ("--residual", st.sampled_from(["plain", "x"]))]),
                                       max_size=4)),
        "generate": lambda: st.tuples(st.just(["trace", "generate"]), st.just([]),
                                      st.lists(st.sampled_from([
                                          ("--method", METHODS), ("--robot", robots),
                                          ("--out", P), ("--truth", P), ("--noise", NOISE),
                                          ("--seed", NUMBERS), ("--count", NUMBERS),
                                          ("--components", st.sampled_from(
                                              ["alpha", "alpha,delta", ",", "gamma,beta"])),
                                          ("--known", st.sampled_from(["L4", "x", ""])),
                                          ("--base-link", st.just("base_link")),
                                          ("--tip-link", st.just("flange"))]), max_size=6)),
        "import": lambda: st.tuples(st.just(["trace", "import"]), st.lists(P, min_size=1,
                                                                           max_size=1),
                                    st.lists(st.sampled_from([
                                        ("--robot", robots), ("--method", METHODS),
                                        ("--out", P), ("--sigma", NOISE),
                                        ("--length-unit", st.sampled_from(["m", "mm", "x"])),
                                        ("--angle-unit", st.sampled_from(["rad", "deg"]))]),
                                        max_size=5)),
        "verify": lambda: st.tuples(st.just(["params", "verify"]), st.lists(P, min_size=1,
                                                                           max_size=1),
                                    st.just([])),
        "export": lambda: st.tuples(st.just(["params", "export"]), st.lists(P, min_size=1,
                                                                           max_size=1),
                                    st.lists(st.sampled_from([("--urdf", P),
                                                              ("--robot-file", P)]),
                                             max_size=2)),
        "simulate": lambda: st.tuples(st.just(["simulate"]), st.just([]), st.lists(
            st.sampled_from([("--robot", robots), ("--truth", P), ("--config", P),
                             ("--endpoints", P), ("--seed", NUMBERS)]), max_size=4)),
        "check": lambda: st.tuples(st.just(["devices", "check"]), st.just([]), st.lists(
            st.sampled_from([("--config", P), ("--endpoints", P), ("--seconds", NUMBERS),
                             ("--robot", st.sampled_from(["agebot-sm", "x"]))]),
            max_size=3)),
        "run": lambda: st.tuples(st.just(["run"]), st.just([]), st.lists(st.sampled_from([
            ("--robot", robots), ("--method", METHODS), ("--out", P), ("--truth", P),
            ("--config", P), ("--count", NUMBERS), ("--seed", NUMBERS),
            ("--sim-seed", NUMBERS), ("--target-std", NUMBERS),
            ("--nominal", st.sampled_from(["k1=nan", "k1=1", "x=2", "k1"])),
            ("--endpoints", P)]), max_size=6)),
        "study": lambda: st.tuples(st.just(["study"]), st.just([]), st.lists(st.sampled_from([
            ("--method", METHODS), ("--robots", NUMBERS), ("--out", P), ("--count", NUMBERS),
            ("--seed", NUMBERS), ("--workers", NUMBERS), ("--noise", NOISE),
            ("--gear", NUMBERS), ("--scheduler", st.sampled_from(["foo", "tcp://h:1"])),
            ("--design", st.sampled_from(["optimal", "x", ""]))]), max_size=6)),
    }

    @st.composite
    def build(draw):
        name = draw(st.sampled_from(sorted(opts)))
        head, pos, pairs = draw(opts[name]())
        argv = list(head) + list(pos)
        for flag, values in pairs:
            argv += [flag, draw(values)]
        if draw(st.booleans()) and name in ("run", "devices"):
            argv.append("--simulate")
        if draw(st.integers(0, 9)) == 0:
            argv.append(draw(st.sampled_from(["--bogus", "-x", "--", "extra"])))
        return argv
    return build()


def _one_run(capsys, monkeypatch, work, argv):
    d, files, node = work
    before = _digests(files)
    _stub_long_work(monkeypatch)
    t0 = time.monotonic()
    try:
        rc = app_module.main(argv)
    except SystemExit as e:
        rc = e.code
    except Accepted:
        rc = 0
    dt = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert rc in (0, 2), (argv, rc, err)
    if rc == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), (argv, err)
    assert "Traceback" not in err, (argv, err)
    assert _digests(files) == before, f"an input changed: {argv}"
    assert not stat.S_ISREG(os.stat(node).st_mode), f"the device became a file: {argv}"
    assert dt < 60, (argv, dt)


def _check_cli(capsys, monkeypatch, work, s):
    d, files, node = work
    out = str(d / "out")

    @s
    @given(argv=argv_strategy(files, node, out))
    def prop(argv):
        with monkeypatch.context() as m:
            _one_run(capsys, m, work, argv)
    prop()


def test_any_arguments_exit_0_or_one_line(capsys, monkeypatch, work):
    _check_cli(capsys, monkeypatch, work, QUICK)


@pytest.mark.slow
def test_any_arguments_exit_0_or_one_line_many(capsys, monkeypatch, work):
    _check_cli(capsys, monkeypatch, work, MANY)


# -- trace import's CSV reader, through app.py ------------------------------------------------
CELLS = st.sampled_from(["", "nan", "inf", "-1e300", "1e400", "--5", "\u00b2", "0_5", "x",
                         '"1"', "1,2", " ", "1e-320", "-0", "0x1", "\ufeff1", "1" * 400])


@st.composite
def _csv_text(draw, lines):
    out = list(lines)
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(out) - 1))
        cells = out[i].split(",")
        op = draw(st.sampled_from(["cell", "drop-cell", "drop-line", "add-cell", "junk"]))
        if op == "cell":
            cells[draw(st.integers(0, len(cells) - 1))] = draw(CELLS)
        elif op == "drop-cell" and len(cells) > 1:
            del cells[draw(st.integers(0, len(cells) - 1))]
        elif op == "add-cell":
            cells.append(draw(CELLS))
        elif op == "drop-line" and len(out) > 2:
            del out[i]
            continue
        else:
            cells = [draw(st.text(max_size=10))]
        out[i] = ",".join(cells)
    return "\n".join(out) + "\n"


def _check_csv(capsys, monkeypatch, work, s):
    d, files, node = work
    lines = open(files["ur5.csv"]).read().splitlines()[:30]

    @s
    @given(text=_csv_text(lines), sigma=st.none() | NOISE)
    def prop(text, sigma):
        p = d / "out" / "m.csv"
        p.write_text(text, encoding="utf-8", errors="surrogatepass")
        argv = ["trace", "import", str(p), "--robot", files["ur5.toml"], "--method",
                "sm-position", "--out", str(d / "out" / "m.jsonl")]
        with monkeypatch.context() as m:
            _one_run(capsys, m, work, argv + (["--sigma", sigma] if sigma else []))
    prop()


def test_any_csv_through_trace_import(capsys, monkeypatch, work):
    _check_csv(capsys, monkeypatch, work, QUICK)


@pytest.mark.slow
def test_any_csv_through_trace_import_many(capsys, monkeypatch, work):
    _check_csv(capsys, monkeypatch, work, MANY)


# -- the TOML readers ------------------------------------------------------------------------
TOML_VALUES = st.sampled_from([
    "1e308", "-1e308", "inf", "-inf", "nan", "0", "-0.0", "1e-320", "99999999999999999999",
    '"x"', '""', "true", "[]", "[1, 2]", "[1e308, -1e308]", "{}", '"\\u0000"', '"a\\nb"',
    "[" * 2000 + "]" * 2000, "1979-05-27", "0x10", "[[1]]", "{a = 1}"])


def _mutations(text: str):
    lines = text.splitlines()

    @st.composite
    def mutate(draw):
        out = list(lines)
        for _ in range(draw(st.integers(1, 3))):
            # the keyed lines of the text as mutated so far (a drop shifts them)
            keyed = [i for i, ln in enumerate(out) if "=" in ln and not ln.lstrip().startswith("#")]
            op = draw(st.sampled_from(["value", "drop", "dup", "bytes", "bom", "junk"]))
            if op == "value" and keyed:
                i = draw(st.sampled_from(keyed))
                key = out[i].split("=", 1)[0]
                out[i] = f"{key}= {draw(TOML_VALUES)}"
            elif op == "drop" and out:
                del out[draw(st.integers(0, len(out) - 1))]
            elif op == "dup" and keyed:
                out.append(out[draw(st.sampled_from(keyed))])
            elif op == "bom" and out:
                out[0] = "\ufeff" + out[0]
            elif op == "junk":
                out.insert(draw(st.integers(0, len(out))), draw(st.text(max_size=12)))
            else:
                out.append(draw(st.text(max_size=20)))
        return "\n".join(out) + "\n"
    return mutate()


ROBOT_TEXT = open(os.path.join(FX, "robots", "ur5-like-dh.toml"), encoding="utf-8").read()
STATION_TEXT = open(os.path.join(FX, "stations", "example-real.toml"), encoding="utf-8").read()


def _reads_or_one_line(read, text):
    try:
        read(text)
    except ConfigError as e:
        assert "\n" not in str(e) and str(e), repr(str(e))


def _robot(text):
    from calibration.robots import get_robot
    from drivers.robot_file import parse_robot_file

    get_robot(parse_robot_file(text, "r.toml"))


def _station(tmp_path):
    def read(text):
        from drivers.config import load_station_config

        p = tmp_path / "st.toml"
        p.write_text(text, encoding="utf-8", errors="surrogatepass")
        load_station_config(p)
    return read


@QUICK
@given(text=_mutations(ROBOT_TEXT))
def test_any_robot_file_reads_or_is_one_line(text):
    _reads_or_one_line(_robot, text)


@QUICK
@given(text=st.text(max_size=300))
def test_any_text_as_a_robot_file(text):
    _reads_or_one_line(_robot, text)


@QUICK
@given(text=_mutations(STATION_TEXT))
def test_any_station_config_reads_or_is_one_line(tmp_path_factory, text):
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return
    _reads_or_one_line(_station(tmp_path_factory.mktemp("st")), text)


@pytest.mark.slow
@MANY
@given(text=_mutations(ROBOT_TEXT) | _mutations(STATION_TEXT))
def test_toml_readers_many(tmp_path_factory, text):
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return
    _reads_or_one_line(_robot, text)
    _reads_or_one_line(_station(tmp_path_factory.mktemp("st")), text)


if __name__ == "__main__":       # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
