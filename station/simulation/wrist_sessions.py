"""Whole simulated wrist sessions over drawn wrists, scored as issue 10 asks.

A wrist drawn around the report's (:func:`drivers.sim.truth.draw_truth`), the
simulator in its own process, one unattended :meth:`station.session.session.Session.run`
from the report's nominal, and the score: q3_off and k3 are compensated (eqs.
112-113), so the calibrated parameters are not compared with the truth's; the
calibrated IK is, on the +-15 deg grid, in actuator units (*actuator
equivalence*), together with the largest orientation the session recorded.
pm-tilt does not identify the heading about the vertical: its IK is judged
with each orientation's heading taken out, and the heading error against the
std the parameter file states for it.
Used by ``bench/bench_wrist_sessions.py`` and the slow session test; nothing here
is used by a real station (it needs the simulator).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.methods.pm_tilt import heading_grid, ik_modulo_heading
from calibration.robots import get_robot
from drivers.sim.truth import SimTruth, draw_truth, save_truth
from station.simulation import sessions

#: std of one reading of the wrist's orientation sensor (0.01 deg)
WRIST_NOISE = {"roll": 1.7e-4, "pitch": 1.7e-4, "yaw": 1.7e-4}
GRID_DEG = 15.0


def wrist_truth(seed: int) -> SimTruth:
    """The wrist drawn with ``default_rng(seed)``, sensor noise :data:`WRIST_NOISE`."""
    return draw_truth("agebot-pm", np.random.default_rng(seed), noise=WRIST_NOISE, seed=seed,
                      comment=f"drawn by station.simulation.wrist_sessions, seed {seed}")


def ik_error(x, truth_xi, box_deg: float = GRID_DEG) -> float:
    """Worst |calibrated IK - true IK| (actuator units) over a 7^3 grid of +-``box_deg``."""
    robot = get_robot("agebot-pm")
    grid = heading_grid(box_deg)
    n = robot.n_params
    return float(np.abs(robot.ik_actuators(grid, np.asarray(x)[:n])
                        - robot.ik_actuators(grid, truth_xi)).max())


def tilt_ik_error(x, truth_xi, box_deg: float = GRID_DEG) -> tuple[float, float]:
    """pm-tilt's judge: ``(worst actuator error of the calibrated IK over the grid with
    each orientation's heading taken out, worst |heading| (deg) taken out)``; the
    heading about the vertical is what pm-tilt does not identify
    (:func:`calibration.methods.pm_tilt.ik_modulo_heading`)."""
    robot = get_robot("agebot-pm")
    err, phi = ik_modulo_heading(robot, heading_grid(box_deg), np.asarray(x)[:robot.n_params],
                                 truth_xi)
    return float(err.max()), float(np.degrees(np.abs(phi).max()))


def max_orientation_deg(poses, truth_xi) -> float:
    """Largest |Euler angle| (deg) of the true wrist at the recorded poses (its FK at
    the recorded actuator values: the inclinometer's roll and pitch are not the
    angles of the box)."""
    if not poses:
        return 0.0
    guess = np.array([p["orientation"] if len(p.get("orientation") or ()) == 3
                      else [*p.get("tilt", (0.0, 0.0)), 0.0] for p in poses], dtype=float)
    X = get_robot("agebot-pm").fk(np.array([p["qm"] for p in poses], dtype=float), truth_xi,
                                  guess=guess)
    return float(np.degrees(np.abs(X).max()))


@dataclass
class WristScore:
    seed: int
    method: str
    completed: bool
    error: str = ""
    ik_error: float = float("nan")
    heading_deg: float = float("nan")      # pm-tilt: worst heading error taken out of ik_error
    heading_std_deg: float = float("nan")  # pm-tilt: the std the fit states for it
    max_deg: float = 0.0
    poses: int = 0
    dropped: int = 0
    rounds: int = 0
    seconds: float = 0.0
    events: dict = field(default_factory=dict)

    @property
    def heading_z(self) -> float:
        """pm-tilt: heading error / its stated std (NaN for the other methods)."""
        return self.heading_deg / self.heading_std_deg

    @property
    def ok(self) -> bool:
        """Complete, IK within 1 unit (pm-tilt: without the heading, whose error must lie
        within 4 of its stated std), nothing recorded beyond 25 deg."""
        heading_ok = self.method != "pm-tilt" or self.heading_z < 4.0
        return self.completed and self.ik_error < 1.0 and self.max_deg < 25.0 and heading_ok


def fast_config(folder: Path, speed: float = 4.0) -> Path:
    """sim-pm.toml with moves ``speed`` times faster (velocity x speed, acceleration
    x speed^2): :func:`station.simulation.sessions.fast_config`."""
    Path(folder).mkdir(parents=True, exist_ok=True)
    return sessions.fast_config("agebot-pm", folder, speed)


def run_wrist_session(truth: SimTruth, folder, *, method: str = "pm-fk", seed: int = 0,
                      request=None, speed: float = 4.0) -> WristScore:
    """One unattended wrist session on the simulated ``truth`` in ``folder``, scored."""
    from station.planning.request import PlanRequest
    from station.recording.trace import read_trace

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_truth(truth, folder / "truth.json")
    run = sessions.simulated_session(truth, folder, method, request or PlanRequest(seed=seed),
                                         fast_config(folder, speed), seed)
    s = run.session
    score = WristScore(seed=seed, method=method, completed=run.completed, error=run.error,
                       seconds=run.seconds)
    score.events = sessions.event_counts(s)
    score.rounds = score.events.get("plan", 0)
    score.dropped = score.events.get("envelope", 0)
    if s.trace_path.exists():
        poses = read_trace(s.trace_path).poses
        score.poses, score.max_deg = len(poses), max_orientation_deg(poses, truth.xi())
    if score.completed:
        x = s.outcome.result.x
        if method == "pm-tilt":
            score.ik_error, score.heading_deg = tilt_ik_error(x, truth.xi())
            (d,) = (d for d in s.outcome.document["not_identified"] if d["direction"] == "heading")
            score.heading_std_deg = float(np.degrees(d["std_rad"]))
        else:
            score.ik_error = ik_error(x, truth.xi())
    return score
