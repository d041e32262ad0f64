"""FIGAROH (PyPI ``figaroh``, on Pinocchio) as the peer of bench_chain.py.

Importing this module fails with ImportError where figaroh is not installed;
bench_chain.py then prints "figaroh not installed".

The same arm and data as bench_chain.py, given to FIGAROH the way its users
give them: the nominal arm as a URDF (the station's own export,
``station.outputs.export.urdf_text``: joints ``joint1..6``, the reflector the fixed
link ``tool0``), a unified YAML config (``full_params`` calibration
level, base and tip frames unknown, one marker with position-only
measurability) and the CSV of joint values and reflector positions. The
calibration is FIGAROH's :class:`figaroh.calibration.BaseCalibration` with the
position residual ``PEE_measured - calc_updated_fkm(...)`` as cost function
(what its examples do for a position-only marker), solved as FIGAROH solves
it (``solve_optimisation``: scipy ``least_squares(method='lm')`` with its
finite-difference Jacobian, one fit, no outlier exclusion). Timed: the
solve; ``initialize`` (data loading, FIGAROH's structural identifiability
analysis) is reported beside it.
"""
from __future__ import annotations

import contextlib
import io
import logging
import math
import os
import tempfile
import time
import warnings

import numpy as np

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # pinocchio/ndcurves converter warnings on import
    import pinocchio as pin
    from figaroh.calibration import BaseCalibration
    from figaroh.calibration.calibration_tools import calc_updated_fkm

from station.outputs.export import urdf_text  # noqa: E402

JOINTS = [f"joint{i}" for i in range(1, 7)]


CONFIG = """\
robot:
  name: "ur5like"
  properties:
    joints:
      active_joints: [{joints}]
tasks:
  calibration:
    enabled: true
    type: kinematic_calibration
    parameters:
      calibration_level: "full_params"
      include_non_geometric: false
      regularization_coefficient: 0.0
      outlier_threshold: 1.0
    kinematics:
      base_frame: "universe"
      tool_frame: "tool0"
    measurements:
      markers:
        - name: "reflector"
          reference_joint: "joint6"
          measurable_dof: [true, true, true, false, false, false]
          sensor_type: "tracker"
      poses:
        base_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        tool_pose: [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    data:
      source_file: "{data}"
      number_of_samples: {n}
"""


class TrackerCalibration(BaseCalibration):
    """FIGAROH calibration with the position residual of one marker."""

    calls = 0

    def cost_function(self, var):
        self.calls += 1
        pee = calc_updated_fkm(self.model, self.data, var, self.q_measured, self.calib_config)
        return self.PEE_measured - pee


class FigarohRun:
    """Build FIGAROH's calibration of bench_chain's problem; ``row`` times it."""

    def __init__(self, robot, model, truth):
        self.model, self.truth = model, truth
        self.dir = tempfile.TemporaryDirectory(prefix="bench-figaroh-")
        d = self.dir.name
        with open(os.path.join(d, "ur5like.urdf"), "w") as f:
            f.write(urdf_text(robot, robot.nominal))
        with open(os.path.join(d, "data.csv"), "w") as f:
            f.write(",".join(["x1", "y1", "z1", *JOINTS]) + "\n")
            for p, q in zip(model.p_m, model.qm):
                f.write(",".join(repr(float(v)) for v in (*p, *q)) + "\n")
        self.config = os.path.join(d, "config.yaml")
        with open(self.config, "w") as f:
            f.write(CONFIG.format(joints=", ".join(f'"{j}"' for j in JOINTS),
                                  data=os.path.join(d, "data.csv"), n=len(model.qm)))
        self.robot = pin.RobotWrapper.BuildFromURDF(os.path.join(d, "ur5like.urdf"))
        # the URDF is the same arm: reflector positions at the nominal agree
        rd = self.robot.model.createData()
        fid = self.robot.model.getFrameId("tool0")
        p_chain = robot.frames(model.qm[:20], robot.nominal)[:, :3, 3]
        for q, p in zip(model.qm[:20], p_chain):
            pin.framesForwardKinematics(self.robot.model, rd, q)
            if np.abs(rd.oMf[fid].translation - p).max() > 1e-12:
                raise AssertionError("the URDF written for FIGAROH is not the bench's arm")
        self.t = self.t_med = None
        self.t_init = None
        self.calib = self.result = None
        self.error = None

    def _quiet(self):
        logging.getLogger("calibration").setLevel(logging.ERROR)
        logging.getLogger("figaroh").setLevel(logging.ERROR)
        return contextlib.redirect_stdout(io.StringIO())

    def setup(self):
        """A fresh calibration object, initialized (not timed in ``t``)."""
        with self._quiet(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            calib = TrackerCalibration(self.robot, self.config)
            # FIGAROH 1.0.2's unified config never sets these; the base and the
            # tip frame are unknown here, as in ours (base and tool calibrated)
            calib.calib_config.setdefault("known_baseframe", False)
            calib.calib_config.setdefault("known_tipframe", False)
            t = time.perf_counter()
            calib.initialize()
            self.t_init = time.perf_counter() - t
        return calib

    def solve(self, calib):
        with self._quiet(), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result, _outliers = calib.solve_optimisation(method="lm", max_iterations=1)
        return result

    def prepare(self, rounds: int):
        """``rounds`` initialized calibration objects (their ``initialize()``, FIGAROH's
        data loading and identifiability analysis, not timed), one per timed call."""
        self._ready = [self.setup() for _ in range(rounds)]

    def timed_solve(self):
        """One solve on a freshly initialized object (what the interleave times)."""
        calib = self._ready.pop()
        calib.calls = 0
        self.calib, self.result = calib, self.solve(calib)

    def set_times(self, times):
        self.t, self.t_med = min(times), float(np.median(times))

    def held_out(self, qm) -> np.ndarray:
        """FIGAROH's calibrated reflector positions at joint values ``qm``."""
        cfg = self.calib.calib_config
        n = cfg["NbSample"]
        cfg["NbSample"] = len(qm)
        try:
            pee = calc_updated_fkm(self.calib.model, self.calib.data, self.result.x,
                                   np.asarray(qm, float), cfg)
        finally:
            cfg["NbSample"] = n
        return pee.reshape(3, -1).T

    def rms(self) -> float:
        return math.sqrt(float(np.mean(self.result.fun ** 2)))

    def reached(self, rms_ours: float, tol: float = 0.01) -> bool:
        """Did FIGAROH reach our optimum (its residual RMS within ``tol`` of ours)?"""
        return self.error is None and self.rms() <= (1 + tol) * rms_ours

    def row(self, t_ours: float, rms_ours: float):
        if self.error:
            return ("figaroh", "ERROR", "-", "-", "-", "-", "-", "-")
        r = self.result
        ok = self.reached(rms_ours)
        status = (f"{r.success} ({r.status})" if ok else
                  f"FAILED: stopped at RMS {self.rms():.2e}, ours {rms_ours:.2e}")
        return ("figaroh", status, r.njev if r.njev is not None else "-",
                self.calib.calls, f"{1e3 * self.t:.1f}", f"{1e3 * self.t_med:.1f}", "-",
                f"{self.t / t_ours:.1f}" if ok else "- (not solved)")

    def summary(self, held_out_error=None) -> str:
        if self.error:
            return f"figaroh failed: {self.error}"
        r, cfg = self.result, self.calib.calib_config
        rms = math.sqrt(float(np.mean(r.fun ** 2)))
        out = (f"    figaroh: {len(r.x)} parameters after its "
               f"identifiability analysis ({cfg['calib_model']}, base and tip frames free); "
               f"lm with finite differences: {self.calib.calls} residual evaluations "
               f"({self.model.n_poses}-pose FK each, finite-difference probes included); residual RMS "
               f"{rms:.2e} m; initialize() {1e3 * self.t_init:.0f} ms (not in the time)")
        if held_out_error is not None:
            out += f"; held-out position error RMS {held_out_error:.2e} m"
        return out
