"""Whole simulated wrist sessions over drawn wrists, scored as issue 10 asks.

A wrist drawn around the report's (:func:`drivers.sim.truth.draw_truth`), the
simulator in its own process, one unattended :meth:`station.session.Session.run`
from the report's nominal, and the score: q3_off and k3 are compensated (eqs.
112-113), so the calibrated parameters are not compared with the truth's; the
calibrated IK is, on the +-15 deg grid, in actuator units (*actuator
equivalence*), together with the largest orientation the session recorded.
Used by ``bench/bench_wrist_sessions.py`` and the slow session test; nothing here
is used by a real station (it needs the simulator).
"""
from __future__ import annotations

import time
import tomllib
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibration.robots import get_robot
from drivers.sim.truth import SimTruth, draw_truth, save_truth

ROOT = Path(__file__).resolve().parents[1]
#: std of one reading of the wrist's orientation sensor (0.01 deg)
WRIST_NOISE = {"roll": 1.7e-4, "pitch": 1.7e-4, "yaw": 1.7e-4}
GRID_DEG = 15.0


def wrist_truth(seed: int) -> SimTruth:
    """The wrist drawn with ``default_rng(seed)``, sensor noise :data:`WRIST_NOISE`."""
    return draw_truth("agebot-pm", np.random.default_rng(seed), noise=WRIST_NOISE, seed=seed,
                      comment=f"drawn by station.sim_wrist, seed {seed}")


def ik_error(x, truth_xi, box_deg: float = GRID_DEG) -> float:
    """Worst |calibrated IK - true IK| (actuator units) over a 7^3 grid of +-``box_deg``."""
    robot = get_robot("agebot-pm")
    g = np.radians(np.linspace(-box_deg, box_deg, 7))
    grid = np.array(np.meshgrid(g, g, g)).reshape(3, -1).T
    n = robot.n_params
    return float(np.abs(robot.ik_actuators(grid, np.asarray(x)[:n])
                        - robot.ik_actuators(grid, truth_xi)).max())


def max_orientation_deg(poses, method: str) -> float:
    """Largest |angle| (deg) the session recorded (orientation, or tilt for pm-tilt)."""
    ch = "tilt" if method == "pm-tilt" else "orientation"
    vals = [np.abs(p[ch]).max() for p in poses if ch in p]
    return float(np.degrees(max(vals))) if vals else 0.0


@dataclass
class WristScore:
    seed: int
    method: str
    completed: bool
    error: str = ""
    ik_error: float = float("nan")
    max_deg: float = 0.0
    poses: int = 0
    dropped: int = 0
    rounds: int = 0
    seconds: float = 0.0
    events: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.completed and self.ik_error < 1.0 and self.max_deg < 25.0


def fast_config(folder: Path, speed: float = 4.0) -> Path:
    """sim-pm.toml with moves ``speed`` times faster (velocity x speed, acceleration
    x speed^2)."""
    path = ROOT / "fixtures" / "stations" / "sim-pm.toml"
    text = path.read_text()
    data = tomllib.loads(text)["canopen"]
    out = text.replace(f"profile_velocity = {data['profile_velocity']!r}",
                       f"profile_velocity = {data['profile_velocity'] * speed!r}")
    out = out.replace(f"profile_acceleration = {data['profile_acceleration']!r}",
                      f"profile_acceleration = {data['profile_acceleration'] * speed ** 2!r}")
    if out == text and speed != 1.0:
        raise ValueError(f"{path}: profile_velocity/profile_acceleration not found to scale")
    Path(folder).mkdir(parents=True, exist_ok=True)
    dest = Path(folder) / "sim-pm.toml"
    dest.write_text(out)
    return dest


def run_wrist_session(truth: SimTruth, folder, *, method: str = "pm-fk", seed: int = 0,
                      request=None, speed: float = 4.0) -> WristScore:
    """One unattended wrist session on the simulated ``truth`` in ``folder``, scored."""
    from drivers.config import load_station_config
    from drivers.endpoints import with_endpoints
    from drivers.sim.server import SimulatorProcess
    from station.planner import PlanRequest
    from station.session import Session
    from station.trace import read_trace

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_truth(truth, folder / "truth.json")
    cfg = fast_config(folder, speed)
    score = WristScore(seed=seed, method=method, completed=False)
    t0 = time.monotonic()
    with SimulatorProcess("agebot-pm", truth=str(folder / "truth.json"), config=str(cfg),
                          seed=seed) as sim:
        config = with_endpoints(load_station_config(cfg), sim.endpoints, source="simulator")
        with Session(config, method, folder / "run",
                     request=request or PlanRequest(seed=seed)) as s:
            try:
                s.run()
                score.completed = True
            except Exception as e:      # the score says what went wrong; the bench goes on
                score.error = f"{type(e).__name__}: {e}"
                (folder / "error.txt").write_text(traceback.format_exc())
    score.seconds = time.monotonic() - t0
    for ev in s.events:
        score.events[ev["kind"]] = score.events.get(ev["kind"], 0) + 1
    score.rounds = sum(1 for ev in s.events if ev["kind"] == "plan")
    score.dropped = score.events.get("envelope", 0)
    if s.trace_path.exists():
        poses = read_trace(s.trace_path).poses
        score.poses, score.max_deg = len(poses), max_orientation_deg(poses, method)
    if score.completed:
        score.ik_error = ik_error(s.outcome.result.x, truth.xi())
    return score
