"""Trace generation from a truth file plus command-line noise (station.simulation.tracegen)."""
import numpy as np
import pytest

from calibration.errors import ConfigError
from calibration.methods import METHODS
from station.planning.request import MUST_KNOW
from station.recording.trace import read_trace
from station.simulation.tracegen import generate_from_truth, parse_noise, reading_noise


def test_parse_noise():
    assert parse_noise(["distance=1e-4", "tilt = 2e-3"]) == {"distance": 1e-4, "tilt": 2e-3}
    for bad in ("distance", "distance=", "=1e-4", "distance=abc", "distance=-1", "distance=nan"):
        with pytest.raises(ConfigError, match="CHANNEL=STD"):
            parse_noise([bad])


def test_reading_noise_tilt_axes():
    # pm-tilt: two axes, from roll/pitch or one value for both
    assert reading_noise("pm-tilt", {"roll": 1e-3}) == {"roll": 1e-3, "tilt": [1e-3, 0.0]}
    assert reading_noise("pm-tilt", {"tilt": 2e-3})["tilt"] == [2e-3, 2e-3]
    # the SM's tilt is one angle: roll/pitch do not turn it into a pair
    assert reading_noise("sm-distance-tilt", {"roll": 1e-3, "tilt": 2e-3})["tilt"] == 2e-3
    assert "tilt" not in reading_noise("sm-distance-tilt", {"roll": 1e-3})


def test_generate_from_truth_noise_and_atomic(tmp_path):
    out = tmp_path / "t.jsonl"
    out.write_text("old\n")
    generate_from_truth(out, "sm-distance-tilt", noise=["distance=1e-4", "tilt=1e-3", "roll=5"],
                        seed=2, count=12)
    tr = read_trace(out)
    assert tr.header["sigma"] == {"distance": 1e-4, "tilt": 1e-3}
    assert len(tr.fit_poses) == 12
    before = out.read_bytes()
    with pytest.raises(ConfigError, match="unknown method"):
        generate_from_truth(out, "no-such-method")
    with pytest.raises(ConfigError, match="truth is for agebot-pm"):
        generate_from_truth(out, "sm-distance", truth="fixtures/truth/agebot-pm.json")
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.jsonl"]
    noisefree = tmp_path / "n.jsonl"
    generate_from_truth(noisefree, "sm-distance-tilt", seed=2, count=12)
    d0 = [p["distance"] for p in read_trace(noisefree).poses]
    d1 = [p["distance"] for p in read_trace(out).poses]
    assert 1e-6 < np.std(np.subtract(d1, d0)) < 1e-3


@pytest.mark.parametrize("method", sorted(m for m, mi in METHODS.items() if not mi.urdf_only))
def test_every_method_generates_on_its_built_in_robot_and_calibrates(tmp_path, method):
    """`app.py trace generate --method M` works for every method on its built-in
    robot (sm-position once failed with a bare "error: sm-position"), and the trace
    calibrates and passes the gate; where the parameters are the truth's own (not
    in a captured base frame, not the wrist's compensated pairs: judged elsewhere by
    their frame or actuator equivalence) it is back at the truth within a few std."""
    from calibration.robots import BUILTIN, get_robot
    from station.fitting.batch import calibrate_trace

    out = tmp_path / f"{method}.jsonl"
    noise = {"pose": "pose=1e-5", "position": "position=1e-5", "distance": "distance=1e-5",
             "tilt": "tilt=1e-4", "orientation": "orientation=1e-4"}
    generate_from_truth(out, method, seed=5, known=MUST_KNOW.get(method, ()),
                        noise=[noise[ch] for ch in METHODS[method].channels])
    trace = read_trace(out)
    assert trace.method == method and len(trace.fit_poses) >= 10
    outcome = calibrate_trace(str(out))
    assert outcome.result.converged, outcome.result.message
    assert outcome.quality.passed, outcome.quality.failures
    if method == "sm-distance-tilt" or METHODS[method].kind != "serial":
        return
    robot = get_robot(BUILTIN[METHODS[method].kind])
    r = outcome.result
    for j, (name, st) in enumerate(zip(r.names, r.status)):
        if st.identifiable and name in robot.param_names:
            err = abs(r.x[j] - robot.true[robot.index(name)])
            if METHODS[method].channels:       # noisy readings: within their std
                assert err < 6 * r.std[j], (name, err / r.std[j])
            else:                              # the touching methods: noise-free
                assert err < 1e-6, (name, err)


def test_sm_markers_generates_on_a_urdf_robot_and_not_on_a_built_in_one(tmp_path):
    """sm-markers has no built-in robot: a URDF robot's trace generates and calibrates
    through the gate with its stated noise; without a URDF, one line says what it takes."""
    from station.fitting.batch import calibrate_trace
    from tests.station.test_cli import app
    from tests.station.urdf_helpers import URDF

    out = tmp_path / "m.jsonl"
    r = app("trace", "generate", "--robot", str(URDF), "--base-link", "base_link", "--tip-link",
            "tool0", "--method", "sm-markers", "--noise", "marker=2e-5", "--seed", "3",
            "--out", str(out))
    assert r.returncode == 0, r.stderr
    outcome = calibrate_trace(str(out))
    assert outcome.quality.passed, outcome.quality.failures
    assert any(c["check"] == "noise" and c["ok"] for c in outcome.quality.checks)
    r = app("trace", "generate", "--method", "sm-markers", "--out", str(tmp_path / "x.jsonl"))
    assert r.returncode == 2 and r.stderr.startswith("error: sm-markers takes a URDF robot")
