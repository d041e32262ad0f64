"""The fit-quality gate (station.fitting.gate) on robots that are not the report's: gross
readings named and left out (or the fit refused naming them), a flipped tilt sign,
a swapped Modbus word order, identical poses, held-out validation; never rc 0 with
a biased result."""
import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import get_robot
from drivers.sim.truth import draw_truth
from station.fitting.batch import calibrate
from station.fitting.verdict import FitQualityError
from station.outputs.params_file import read_params
from station.recording.trace import read_trace
from station.recording.trace_writer import write_trace
from station.simulation.tracegen import generate

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
NOISE = {"distance": 1e-4, "tilt": 2e-4}


def app(*args):
    return subprocess.run([sys.executable, os.path.join(ROOT, "app.py"), *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


def make_trace(tmp_path, seed, corrupt=None, method="sm-distance-tilt", noise=NOISE, **kw):
    """A trace of a robot drawn around the nominal; ``corrupt(poses)`` edits its readings.
    Returns the path and the true parameter vector."""
    if method.startswith("pm"):
        # the trace generator cannot yet plan for a wrist drawn around the nominal
        # (its rods do not reach the planned poses): the report's wrist
        xi = get_robot("agebot-pm").true
    else:
        xi = draw_truth("agebot-sm", np.random.default_rng(seed)).xi()
    header, ref, poses = generate(method, xi, noise=noise, seed=seed, **kw)
    if corrupt is not None:
        corrupt(poses)
    path = tmp_path / f"{method}-{seed}.jsonl"
    write_trace(path, header, ref, poses)
    return str(path), np.asarray(xi), ref


def errors_in_std(outcome, xi, ref):
    """(calibrated - true) / std of every calibrated parameter; sm-distance-tilt's
    theta0, a0, q1_off against the truth in the captured base frame."""
    robot = get_robot("agebot-sm")
    truth = reframe_nominal(robot, xi, np.asarray(ref["qm"])) if ref else xi
    res = outcome.result
    return {n: (res.x[j] - truth[j]) / res.std[j]
            for j, (n, st) in enumerate(zip(res.names, res.status)) if st.identifiable}


def test_a_clean_trace_passes_and_the_file_records_the_gate(tmp_path):
    path, xi, ref = make_trace(tmp_path, 0)
    out = tmp_path / "params.json"
    r = app("batch", path, "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "outliers: none" in r.stdout and "fit quality: passed" in r.stdout
    q = read_params(out)["fit"]["quality"]
    assert q["passed"] and not q["accepted"] and q["outliers"] == []
    assert {c["check"] for c in q["checks"]} >= {"outliers", "noise", "poses", "plausible"}


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("offset,pose", [(0.10, 5), (0.05, 7), (0.01, 3)])
def test_one_gross_reading_is_named_left_out_and_the_result_unbiased(tmp_path, seed, offset,
                                                                     pose):
    """One distance reading 10, 5 or 1 cm off (1000, 500, 100 sigma): the pose is named
    as an outlier and the result lies within 5 std of the truth, or the fit is refused
    naming the pose; never accepted with a bias."""
    def corrupt(poses):
        poses[pose]["distance"] += offset

    path, xi, ref = make_trace(tmp_path, seed, corrupt)
    try:
        outcome = calibrate(read_trace(path))
    except CalibrationError as e:
        assert f"pose {pose} distance" in str(e)
        return
    assert [(o["pose"], o["channel"]) for o in outcome.quality.outliers] == [(pose, "distance")]
    z = errors_in_std(outcome, xi, ref)
    assert max(abs(v) for v in z.values()) < 5, z


def test_batch_names_the_outlier_in_output_and_parameter_file(tmp_path):
    path, _, _ = make_trace(tmp_path, 0, lambda p: p[5].update(distance=p[5]["distance"] + 0.1))
    out = tmp_path / "params.json"
    r = app("batch", path, "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "outlier excluded: pose 5 distance" in r.stdout
    q = read_params(out)["fit"]["quality"]
    assert [(o["pose"], o["channel"]) for o in q["outliers"]] == [(5, "distance")]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_flipped_tilt_sign_exits_non_zero_and_writes_nothing(tmp_path, seed):
    def flip(poses):
        for p in poses:
            p["tilt"] = -p["tilt"]

    path, _, _ = make_trace(tmp_path, seed, flip)
    out = tmp_path / "params.json"
    r = app("batch", path, "--out", str(out))
    assert r.returncode != 0
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert ("quality gate" in r.stderr or "did not converge" in r.stderr), r.stderr
    assert not out.exists()
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".params")]


def test_swapped_modbus_word_order_distances_are_refused(tmp_path):
    """-1329 m: the two 16-bit words of the draw-wire's count swapped."""
    def swap(poses):
        for p in poses:
            p["distance"] = -1329.1 + p["distance"]

    path, _, _ = make_trace(tmp_path, 0, swap)
    out = tmp_path / "params.json"
    r = app("batch", path, "--out", str(out))
    assert r.returncode != 0 and not out.exists()
    assert "distance -1328" in r.stderr and "word order" in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1


def test_all_poses_identical_are_refused(tmp_path):
    def same(poses):
        for p in poses:
            p.update(qm=poses[0]["qm"], distance=poses[0]["distance"], tilt=poses[0]["tilt"])

    path, _, _ = make_trace(tmp_path, 2, same)
    with pytest.raises(FitQualityError, match=r"only 1 distinct of 33 poses"):
        calibrate(read_trace(path), out=str(tmp_path / "p.json"))
    assert not (tmp_path / "p.json").exists()


def test_accept_poor_fit_writes_the_file_and_records_it(tmp_path):
    def flip(poses):
        for p in poses:
            p["tilt"] = -p["tilt"]

    path, _, _ = make_trace(tmp_path, 0, flip)
    out = tmp_path / "params.json"
    r = app("batch", path, "--out", str(out), "--accept-poor-fit")
    assert r.returncode == 0, r.stderr
    assert "accepted by the operator" in r.stdout
    q = read_params(out)["fit"]["quality"]
    assert q["accepted"] and not q["passed"]
    assert any(c["check"] == "plausible" and not c["ok"] for c in q["checks"])
    assert app("params", "verify", str(out)).returncode == 0


def test_held_out_poses_predicted_worse_than_the_start_fail_the_gate(tmp_path):
    """Held-out poses whose tilt sign is flipped (the inclinometer re-mounted between
    the fit and the validation poses): the calibrated model predicts them worse
    than the start values did."""
    def hold_out(poses):
        for p in poses[-8:]:
            p["use"] = "validation"
            p["tilt"] = -p["tilt"]

    path, _, _ = make_trace(tmp_path, 0, hold_out, count=41)
    with pytest.raises(FitQualityError, match=r"validation: tilt RMS .* worse than the start"):
        calibrate(read_trace(path))


def test_held_out_poses_that_agree_pass(tmp_path):
    def hold_out(poses):
        for p in poses[-8:]:
            p["use"] = "validation"

    path, _, _ = make_trace(tmp_path, 0, hold_out, count=41)
    outcome = calibrate(read_trace(path))
    checks = [c for c in outcome.quality.checks if c["check"] == "validation"]
    assert len(checks) == 2 and all(c["ok"] for c in checks)
    assert outcome.validation and outcome.validation[0]["n"] == 8


def test_stated_sigma_too_small_fails_the_noise_check(tmp_path):
    """Readings ten times noisier than the header's sigma says."""
    path, _, _ = make_trace(tmp_path, 1, noise={"distance": 1e-3, "tilt": 2e-3})
    lines = open(path).read().splitlines()
    head = json.loads(lines[0])
    head["sigma"] = NOISE
    with open(path, "w") as f:
        f.write("\n".join([json.dumps(head)] + lines[1:]) + "\n")
    with pytest.raises(FitQualityError, match=r"noise: distance residuals do not fit the stated"):
        calibrate(read_trace(path))


@pytest.mark.parametrize("method", ["sm-distance", "sm-full-pose", "pm-fk"])
def test_other_methods_clean_pass_and_a_gross_reading_is_named(tmp_path, method):
    ch = {"sm-distance": "distance", "sm-full-pose": "pose", "pm-fk": "orientation"}[method]
    noise = {ch: 1e-4}
    clean, _, _ = make_trace(tmp_path, 4, method=method, noise=noise)
    assert calibrate(read_trace(clean)).quality.outliers == []

    def corrupt(poses):
        v = poses[6][ch]
        if isinstance(v, list):
            v[1] += 0.02
        else:
            poses[6][ch] = v + 0.02

    (tmp_path / "bad").mkdir()
    bad, _, _ = make_trace(tmp_path / "bad", 4, corrupt, method=method, noise=noise)
    try:
        outcome = calibrate(read_trace(bad))
    except CalibrationError as e:
        assert "pose 6" in str(e)
        return
    assert [o["pose"] for o in outcome.quality.outliers] == [6]


@pytest.mark.slow
def test_false_alarm_rate_on_clean_traces(tmp_path):
    """Clean noisy traces of 60 robots drawn around the nominal: no pose is lost
    (the test's family-wise alpha is 1e-3 per trace)."""
    lost = []
    for seed in range(100, 160):
        path, _, _ = make_trace(tmp_path, seed)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                outcome = calibrate(read_trace(path))
        except CalibrationError:
            continue          # a fit the gate refuses is not a lost pose
        if outcome.quality.outliers:
            lost.append(seed)
        os.unlink(path)
    assert len(lost) <= 1, lost


@pytest.mark.parametrize("method, n_r, minimum", [("sm-distance-tilt", 14, 35),
                                                   ("sm-distance", 10, 50)])
def test_the_plans_eq60_minimum_is_the_gates(tmp_path, method, n_r, minimum):
    """A session's trace (its draw-wire zero a reading: distance_off calibrated):
    the planner's eq. 60 minimum is the one the gate checks (the plan said 33 for
    sm-distance-tilt where the gate asked for 35); a trace with an exact zero keeps
    docs/models.md's N_R."""
    from calibration.identifiability import minimum_poses
    from station.fitting.pose_count import minimum_count, parameter_count

    def zero_is_a_reading(path):
        lines = open(path).read().splitlines()
        ref = json.loads(lines[1])
        ref["zero"] = "reading"
        with open(path, "w") as f:
            f.write("\n".join([lines[0], json.dumps(ref)] + lines[2:]) + "\n")

    noise = NOISE if method == "sm-distance-tilt" else {"distance": NOISE["distance"]}
    path, _, _ = make_trace(tmp_path, 5, method=method, noise=noise, count=minimum + 4)
    zero_is_a_reading(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        outcome = calibrate(read_trace(path))
    poses = next(c for c in outcome.quality.checks if c["check"] == "poses")
    assert poses["ok"] and poses["identifiable"] == poses["expected_identifiable"] == n_r
    assert parameter_count(method) == n_r
    assert minimum_count(method) == minimum_poses(poses["identifiable"], outcome.model.p) == minimum
    assert minimum_count(method, distance_zero="exact") == minimum_poses(n_r - 1, outcome.model.p)
