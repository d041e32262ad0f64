"""The final fit of a robot file's arm by sm-distance stays at the minimum its data define.

``station.fitting.batch._fit`` always tries a second start grown with the data (``staged_start``)
for the AGEBOT arm's distance methods and keeps the fit that explains the readings
better. On a robot file's arm that second start moved parameters the data do not
identify but that influence the model (the UR5-like file's held gear ratios ``k1``..``k6``:
its partial fits freed them), the final fit then held them there, and the calibrated
parameters absorbed it: 0.8-3.5 std off the minimum of the same readings (5 of 6
drawn arms), 0.3-0.5 std over the pooled sessions. Only the pooled session test
(``test_session_pooled.py``, slow) saw that as a bias; here one generated trace shows it
directly, against the fit of the same readings started at the truth. The cause is
fixed too (``station.fitting.start_values.fixed_for_rows`` holds a robot file's ``fixed``
parameters in every partial fit): ``test_the_grown_start_holds_the_files_fixed_parameters``.
"""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from calibration.robots import get_robot
from calibration.solver import SolverOptions, solve
from calibration.methods import build
from station.fitting import batch
from station.simulation import tracegen_serial
from station.fitting.start_values import staged_start
from station.simulation.serial_sessions import SERIAL_NOISE, equivalent_truth, serial_truth, serial_truth_vector
from station.recording.trace import read_trace
from station.recording.trace_writer import write_trace

ROOT = Path(__file__).resolve().parents[2]
UR5 = ROOT / "fixtures" / "robots" / "ur5-like-hayati.toml"
#: of the reported std: the fit started at the nominal and the one started at the
#: truth reach one minimum (1e-8 std apart here, 7e-6 at worst over 6 more arms); from
#: the grown start the result was 0.79 (seed 8740) and 3.5 (8741) std off
SAME_MINIMUM = 0.05


@pytest.mark.parametrize("seed,stated", [(8740, True), (8741, False)])
def test_robot_file_sm_distance_is_fitted_to_its_readings_minimum(tmp_path, seed, stated):
    """A UR5-like arm drawn around the file's nominal, the draw-wire's noise; its sigma
    stated in the trace's header or not (a session's trace states none)."""
    truth = serial_truth(UR5, seed, "test_batch_start_robot_file")
    robot = get_robot(truth.spec)
    header, reference, poses = tracegen_serial.generate(
        robot, "sm-distance", truth.xi(), seed=seed, noise={"distance": SERIAL_NOISE["distance"]})
    if not stated:
        del header["sigma"]
    path = tmp_path / "trace.jsonl"
    write_trace(path, header, reference, poses)
    out = batch.calibrate(read_trace(path))        # what `app.py batch` runs
    res, model = out.result, out.model
    assert out.quality.passed and out.quality.outliers == [], out.quality.summary()
    ok = np.array([st.identifiable for st in res.status])
    assert ok.sum() >= 20, ok.sum()
    # the truth in the method's terms (equivalent_truth): the identifiable parameters a fit
    # of noise-free readings of the truth gives, the rest held at the trace's start values
    x_truth = serial_truth_vector(model, truth, {})
    at_start = SimpleNamespace(x=np.where(ok, x_truth, model.x0), names=res.names,
                               status=res.status, sigma=res.sigma)
    x_eq, left = equivalent_truth(model, at_start, x_truth)
    assert left < 1e-3, left
    # the minimum of these readings: their fit started there
    x0 = model.x0
    model.x0 = x_eq
    try:
        ref = solve(model, SolverOptions(fixed=tuple(robot.fixed), sigma=res.sigma))
    finally:
        model.x0 = x0
    assert ref.converged
    z_ref = (res.x - ref.x)[ok] / res.std[ok]
    z_truth = (res.x - x_eq)[ok] / res.std[ok]
    names = [n for n, o in zip(res.names, ok) if o]
    print(f"seed {seed}: max |result - minimum| / std {np.abs(z_ref).max():.3g}, "
          f"max |result - truth| / std {np.abs(z_truth).max():.3g}")
    assert np.abs(z_ref).max() < SAME_MINIMUM, dict(zip(names, np.round(z_ref, 3)))
    assert np.abs(z_truth).max() < 5.0, dict(zip(names, np.round(z_truth, 2)))
    # what the data do not identify stays at the trace's start values, the robot
    # file's held parameters (fixed = k1..k6) among them
    held = [n for n, st in zip(res.names, res.status) if not st.identifiable]
    moved = {n: float(res.x[j] - model.x0[j]) for j, n in enumerate(res.names)
             if n in held and res.x[j] != model.x0[j]}
    assert not moved, moved
    assert set(robot.fixed) <= set(held)


def test_the_grown_start_holds_the_files_fixed_parameters(tmp_path):
    """The second start itself (``staged_start``: fits of the first quarter, half and
    three quarters of the poses) leaves the robot file's ``fixed`` parameters at their
    start values, and the fit from it lands at the same minimum as the one from the
    nominal: a robot file's final fit may be grown from it where the first fails."""
    seed = 8742
    truth = serial_truth(UR5, seed, "test_batch_start_robot_file")
    robot = get_robot(truth.spec)
    header, reference, poses = tracegen_serial.generate(
        robot, "sm-distance", truth.xi(), seed=seed, noise={"distance": SERIAL_NOISE["distance"]})
    path = tmp_path / "trace.jsonl"
    write_trace(path, header, reference, poses)
    out = batch.calibrate(read_trace(path))
    model, res = out.model, out.result
    data = read_trace(path).method_data("sm-distance")
    x_grown = staged_start("sm-distance", robot, data, model.x0)
    assert x_grown is not None
    fixed = [robot.index(n) for n in robot.fixed]
    assert np.array_equal(x_grown[fixed], np.asarray(model.x0)[fixed]), \
        dict(zip(robot.fixed, x_grown[fixed] - np.asarray(model.x0)[fixed]))
    grown = solve(build("sm-distance", robot, data, x_grown),
                  SolverOptions(fixed=tuple(robot.fixed), sigma=res.sigma))
    ok = np.array([st.identifiable for st in res.status])
    z = (grown.x - res.x)[ok] / res.std[ok]
    assert np.abs(z).max() < SAME_MINIMUM, np.round(z, 3)


def test_far_above_noise_reads_the_residual_not_the_stated_sigma():
    """With every sigma stated the fit's sigma is the stated one, so the residual is what
    tells a local minimum (RMS 1.6 mm against 1e-5 m stated) from a fit at the noise."""
    far = SimpleNamespace(sigma={"distance": 1e-5}, residual_rms={"distance": 1.64e-3})
    near = SimpleNamespace(sigma={"distance": 1e-5}, residual_rms={"distance": 0.95e-5})
    assert batch._far_above_noise(far, {"distance": 1e-5})
    assert not batch._far_above_noise(near, {"distance": 1e-5})
    assert not batch._far_above_noise(far, None)
