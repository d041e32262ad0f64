"""A URDF robot measured by a point instrument at the station (``sm-markers``, a motion
capture: :mod:`drivers.mocap`), the session's robot kind (:mod:`station.session.robot_kinds`).

No reference: the instrument's frame and the points on the tool are calibrated with the
robot, and estimated first from the scout round (the same reference-free start as an
imported trace's, :func:`station.recording.import_markers.start_values`, which also
refuses readings a unit, a mirror or a wrong joint makes inconsistent with the robot).
The rounds (:mod:`station.planning.marker_plan`):

* round 0, the scout: a few poses in a small box about home, every joint moved, the points
  facing up (the frame is not known yet: :meth:`MarkersKind.plan`);
* round 1: :data:`MIDDLE_SCALE` of the joints' box about home, an eighth of the count, D-optimal
  given the scout, every point visible under the frame and points estimated so far;
* round 2: the whole box (the limits less a margin), the requested count (default twice
  eq. 60) and the held-out poses, D-optimal given everything measured.

Between rounds the estimate is made again from every fit pose recorded. While moving, the
live watch compares each point the instrument sees with where the current estimate puts
it (:meth:`MarkersKind.predictor`). A point not seen at a pose is a pose with fewer points
(``null`` in the record), never a fault; a pose where no point is seen is not recorded
(a skip event says so, and a resumed session does not measure it again).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from calibration.errors import ConfigError, StationError
from calibration.methods.sm_markers import marker_names
from station.planning import marker_plan
from station.planning.arm_rounds import EARLY_SHARE
from station.recording import resume
from station.recording.planned_pose import PlannedPose
from station.session.robot_kinds import SerialKind

SCOUT_SCALE = 0.3
MIDDLE_SCALE = 0.6
#: the scout's points face up within this share of the config's ``view_angle_deg``: the
#: lines of sight to cameras above the robot are not vertical (20-30 degrees off where
#: the tool is a metre from below the viewpoint), and at the whole angle half the scout's
#: poses were turned away from them (seeds 1-20 of the M-10iA-like arm: 2 to 7 of 8
#: seen, 4 on average; at half the angle all 8 of seeds 1-40)
SCOUT_FACING = 0.5
LAST = 2                       # the last round's number


def sight_of(cfg) -> marker_plan.Sight:
    """The planner's :class:`~station.planning.marker_plan.Sight` of a ``[mocap]`` section."""
    return marker_plan.Sight(volume_min=tuple(cfg.volume_min), volume_max=tuple(cfg.volume_max),
                             viewpoint=tuple(cfg.viewpoint),
                             max_angle=math.radians(cfg.view_angle_deg),
                             outward=(None if cfg.outward is None
                                      else tuple(map(tuple, cfg.outward))))


class MarkersKind(SerialKind):
    """A URDF robot's arm with points on its tool (module doc)."""

    def __init__(self, session):
        super().__init__(session)
        cfg = session.config.mocap
        if cfg is None:
            raise ConfigError("sm-markers at the station needs a point instrument: a [mocap] "
                              "section (docs/urdf-robots.md)", source=session.config.source,
                              key="mocap")
        self.labels = tuple(cfg.labels)
        self.sight = sight_of(cfg)
        self._estimate: tuple[np.ndarray, np.ndarray, int] | None = None

    @property
    def n_points(self) -> int:
        return len(self.labels)

    def reference_target(self):
        return None, "no reference", ""

    def minimum_count(self) -> int:
        if self._min_count is None:
            s = self.s
            x, u = self.estimate()
            home = marker_plan.home_qm(s.robot, s.config.envelope.qm_range)
            box = marker_plan.pose_box(s.robot, s.config.envelope.qm_range, centre=home)
            qm = np.random.default_rng(0).uniform(box[:, 0], box[:, 1],
                                                  size=(200, s.robot.n_actuators))
            self._min_count = marker_plan.fit_count(s.robot, np.r_[x, u.reshape(-1)], qm, 1.0)
        return self._min_count

    # -- the estimate of the frame and the points ------------------------------------------
    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(xi, points)``: the robot's start values with the instrument's frame, and the
        points on the tool, as the fit poses recorded so far place them (the URDF's
        values and the tip's origin before any is recorded)."""
        s = self.s
        fit = [r for r in s.measured.values() if r.get("use", "fit") == "fit"
               and any(c is not None for c in r.get("markers") or ())]
        if self._estimate is not None and self._estimate[2] == len(fit):
            return self._estimate[0], self._estimate[1]
        xi = np.array(s.nominal, dtype=float)
        u = np.zeros((self.n_points, 3))
        if len(fit) >= 3:
            from station.recording.import_markers import pose_arrays, start_values

            qm, pts = pose_arrays(sorted(fit, key=lambda r: r["index"]))
            start = start_values(s.robot, qm, pts, "the poses recorded so far")
            names = marker_names(self.n_points)
            for k, v in start.items():
                if k in names:
                    j = names.index(k)
                    u[j // 3, j % 3] = v
                else:
                    xi[s.robot.index(k)] = v
        self._estimate = (xi, u, len(fit))
        return xi, u

    @property
    def last_estimate(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(xi, points)`` as :meth:`estimate` last made it from three fit poses or more,
        else None. Read, not computed: safe from another thread while the session's
        worker measures (the wizard's picture)."""
        est = self._estimate
        return None if est is None or est[2] < 3 else (est[0], est[1])

    # -- rounds ----------------------------------------------------------------------------
    def _rounds_planned(self) -> list[int]:
        return [int(e["markers_round"]) for e in self.s.events
                if e.get("kind") == "plan" and "markers_round" in e]

    def plan(self) -> list[PlannedPose]:
        """Round 0, the scout: :data:`~station.planning.marker_plan.SCOUT_POSES` poses in
        :data:`SCOUT_SCALE` of the joints' box about home (the URDF's zero), D-optimal at
        the URDF's values. The instrument's frame is not known yet, so the points are
        required to face up (within :data:`SCOUT_FACING` of the config's angle of the
        base link's z: cameras above the robot, as in a motion-capture room) rather than
        to face a viewpoint, where the config states the points' outward directions
        (``[mocap] outward``; without them nothing is known of where the points face
        before they are seen, and the scout is planned for the joints alone)."""
        s = self.s
        up = marker_plan.Sight(volume_min=(-1e3,) * 3, volume_max=(1e3,) * 3,
                               viewpoint=(0.0, 0.0, 1e3),
                               max_angle=SCOUT_FACING * self.sight.max_angle,
                               outward=self.sight.outward)
        req = dataclasses.replace(s.request, count=marker_plan.SCOUT_POSES, validation=0,
                                  target=None)
        qm, use, design = marker_plan.plan(s.robot, s.nominal, np.zeros((self.n_points, 3)), up,
                                           req, qm_range=s.config.envelope.qm_range,
                                           scale=SCOUT_SCALE)
        poses = self._poses(qm, use, 0, 0)
        s._set_plan(poses, replace=True, markers_round=0)
        return poses

    def _here(self):
        s = self.s
        if s.rig is not None and all(d.is_open for d in s.rig.devices):
            return np.array(s.qm(), dtype=float)
        return None

    def _poses(self, qm, use, rnd: int, first: int) -> list[PlannedPose]:
        s = self.s
        xi, u = self.estimate()
        X = s.robot.fk(np.atleast_2d(qm), xi)
        return [PlannedPose(first + k, tuple(map(float, q)), tuple(map(float, x)), v, rnd)
                for k, (q, x, v) in enumerate(zip(np.atleast_2d(qm), X, use))]

    def rounds_complete(self) -> bool:
        done = self._rounds_planned()
        return bool(done) and max(done) >= LAST

    def next_round(self) -> bool:
        s = self.s
        done = self._rounds_planned()
        if not done or max(done) >= LAST:
            return False
        rnd = max(done) + 1
        try:
            xi, u = self.estimate()
        except StationError as e:
            s._event("stop", f"the scout's readings do not follow the robot: {e}")
            raise
        fit = sorted((r for r in s.measured.values() if r.get("use", "fit") == "fit"),
                     key=lambda r: r["index"])
        measured = np.array([r["qm"] for r in fit], dtype=float).reshape(-1, s.robot.n_actuators)
        count = s.request.count
        if rnd < LAST:
            early = max(marker_plan.SCOUT_POSES, math.ceil((count or 0) / EARLY_SHARE))
            req = dataclasses.replace(s.request, count=early, validation=0)
            scale = MIDDLE_SCALE
        else:
            req, scale = s.request, 1.0
        qm, use, design = marker_plan.plan(
            s.robot, xi, u, self.sight, req, qm_range=s.config.envelope.qm_range,
            start_qm=self._here(), scale=scale, measured_qm=measured)
        nxt = max(p.index for p in s.plan_poses) + 1
        poses = self._poses(qm, use, rnd, nxt)
        s._set_plan(poses, replace=False, markers_round=rnd, design=design)
        return True

    def plan_text(self, poses, n_val: int, unit: str, how: str, box_scale) -> str:
        rnd = poses[0].round if poses else 0
        if rnd == 0:
            facing = "the points facing up; " if self.sight.outward is not None else ""
            return (f"scout round: planned {len(poses)} poses near home (the URDF's zero), "
                    f"{facing}the instrument's frame and the points on the tool estimated "
                    "from them plan the next rounds, each in a wider box")
        return (f"round {rnd}: planned {len(poses)} poses ({n_val} held out for validation), "
                f"every point inside the measuring volume and facing the instrument, "
                f"{len(self.s.plan_poses)} in all so far")

    def stage(self, pose: PlannedPose):
        s = self.s
        same = [q.index for q in s.plan_poses if q.round == pose.round]
        done = sum(i in s.measured or i in s.skipped for i in same)
        return ("scout" if pose.round == 0 else f"round {pose.round}"), done, len(same)

    # -- readings --------------------------------------------------------------------------
    def reading_record(self, m: dict) -> dict:
        pts = []
        for j in range(1, self.n_points + 1):
            p = [m.get(f"m{j}_{c}", math.nan) for c in "xyz"]
            pts.append([float(v) for v in p] if all(math.isfinite(v) for v in p) else None)
        return {"markers": pts}

    def watch(self, pose: PlannedPose, rec: dict) -> bool:
        """A pose where the instrument sees no point is not recorded (nothing of it to
        calibrate with), and not measured again on resume; fewer points are a pose."""
        if any(c is not None for c in rec.get("markers") or ()):
            return True
        self.s._skip(pose, f"pose {pose.index} not recorded: the instrument saw no point on "
                     "the tool there (occluded, or turned away)", resume.DROPPED)
        return False

    def predictor(self):
        """Each point where the current estimate puts it (m, the instrument's frame), once
        the scout has placed the frame: from round 1 on (None before: not watched). The
        scout's first poses do not place it yet: on three poses of its small box the
        registration stopped 35 mm (median) from the readings where the nominal robot in
        the true frame is 7.5 mm from them, which refused a sound session (seed 17 of
        bench/bench_urdf_sessions.py, when half the scout's poses were turned away); the
        scout as a whole is judged where round 1 is planned (:meth:`next_round`)."""
        s = self.s
        fit = [r for r in s.measured.values() if r.get("use", "fit") == "fit"]
        if len(fit) < 3 or max(self._rounds_planned(), default=0) < 1:
            return None
        xi, u = self.estimate()
        robot = s.robot

        def predict(qm):
            qm = np.asarray(qm, dtype=float)
            T = robot.frames(np.atleast_2d(qm), xi)
            p = T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], u)
            out = {f"m{j + 1}_{c}": p[:, j, i] for j in range(len(u))
                   for i, c in enumerate("xyz")}
            return out if qm.ndim == 2 else {k: float(v[0]) for k, v in out.items()}
        return predict

    def envelope(self, env):
        """The config's envelope, each point's coordinates watched with the ``marker``
        tolerance (``[envelope.tolerance] marker``, m)."""
        tol = env.tolerance.get("marker")
        if tol is None:
            return env
        more = {f"m{j}_{c}": tol for j in range(1, self.n_points + 1) for c in "xyz"}
        return dataclasses.replace(env, tolerance={**env.tolerance, **more})

    def restore(self, events: list[dict]) -> None:
        self._estimate = None

    def header(self) -> dict:
        return {"markers": self.n_points, "labels": list(self.labels)}

