"""The simulated motion-capture room of a URDF robot's truth: what the cameras see.

Each frame's markers are the truth's points on the tool with the true robot where its
axes are now (:func:`drivers.sim.urdf_truth.true_points`) and the truth's ``marker``
noise, drawn as the simulated robot draws every reading's: a new draw per frame, or with
``--pose-noise`` (which ``run --simulate`` uses) at rest a function of the seed and the
pose, the same in every frame, of the std the mean of the config's ``frames`` has, so
that the same command reads the same values; a point outside the
station config's measuring volume or facing away from its viewpoint by more than its
angle is not seen (NaN), as a real room would not see it
(:func:`drivers.sim.urdf_truth.seen_mask`). The QTM real-time server
(:mod:`drivers.sim.mocap_sim`) adds the faults.
"""
from __future__ import annotations

import math

import numpy as np

from calibration.errors import ConfigError

#: a marker of the room QTM labels as well, away from the robot (not on the tool)
ROOM_MARKER = "room_ref"


def points_function(robot, truth, cfg):
    """``f() -> (M, 3)`` the markers on the tool the room sees now (m, instrument frame)."""
    from drivers.sim.urdf_truth import seen_mask, true_points

    volume = (np.asarray(cfg.volume_min, dtype=float), np.asarray(cfg.volume_max, dtype=float))
    angle = math.radians(cfg.view_angle_deg)

    def points() -> np.ndarray:
        qm = robot.qm()
        p = true_points(truth, robot.model, robot._xi, qm)
        noise = robot._noise("marker", p.shape)
        if robot.pose_noise and robot.target_reached():
            noise = noise / math.sqrt(cfg.frames)    # the mean of the N frames the station takes
        p = p + noise
        seen = seen_mask(truth, robot.model, robot._xi, qm, volume, cfg.viewpoint, angle,
                         cfg.outward)
        p[~seen] = np.nan
        return p

    return points


def start_mocap(robot, truth, cfg, seed: int | None):
    """The QTM real-time server of the simulated station (started), its labels the
    config's, or None where the truth has no points on the tool."""
    from drivers.sim.mocap_sim import SimQTM

    if truth.points is None:
        raise ConfigError("the station config has a motion capture ([mocap]) and the truth "
                          "file no points on the tool (a URDF robot's truth has them)",
                          source=truth.source, key="points_on_tool")
    if len(cfg.labels) != len(truth.points):
        raise ConfigError(f"[mocap] labels names {len(cfg.labels)} markers, the truth has "
                          f"{len(truth.points)} points on the tool", source=truth.source,
                          key="points_on_tool")
    rng = np.random.default_rng(None if seed is None else [seed, 0x5155])
    return SimQTM(points_function(robot, truth, cfg), labels=tuple(cfg.labels), rng=rng,
                  extra={ROOM_MARKER: tuple(float(v) for v in cfg.volume_min)}).start()


#: the simulated room: its volume the robot's reach and this margin, its cameras this
#: far above the volume's top, seeing a marker that faces them within this angle
ROOM_MARGIN = 0.3        # m
CAMERA_HEIGHT = 1.5      # m
VIEW_ANGLE_DEG = 80.0


def room_section(truth) -> dict:
    """The ``[mocap]`` section of the simulated station of ``truth`` (a URDF robot's):
    labels ``tool1 .. toolM``, the volume the robot's reach and :data:`ROOM_MARGIN` in the
    instrument's frame, the viewpoint above it, the markers facing along the tip link's z
    (a marker tree on the flange)."""
    from drivers.sim.urdf_truth import frame_matrix

    model = truth.model()
    xi = truth.xi()
    lo, hi = model.limits[:, 0], model.limits[:, 1]
    qm = np.random.default_rng(0).uniform(lo, hi, size=(2000, len(lo)))
    reach = float(np.max(np.linalg.norm(model.frames(qm, xi)[:, :3, 3], axis=1))) + 0.2
    corners = np.array([[x, y, z] for x in (-reach, reach) for y in (-reach, reach)
                        for z in (-0.1, reach)])
    T = frame_matrix(truth.frame)
    c = corners @ T[:3, :3].T + T[:3, 3]
    vmin, vmax = c.min(axis=0) - ROOM_MARGIN, c.max(axis=0) + ROOM_MARGIN
    view = [float((vmin[0] + vmax[0]) / 2), float((vmin[1] + vmax[1]) / 2),
            float(vmax[2] + CAMERA_HEIGHT)]
    return {"host": "@endpoints", "port": "@endpoints",
            "labels": [f"tool{j}" for j in range(1, len(truth.points) + 1)],
            "frames": 10, "timeout": 2.0,
            "volume": {"min": [round(float(v), 3) for v in vmin],
                       "max": [round(float(v), 3) for v in vmax]},
            "viewpoint": [round(v, 3) for v in view], "view_angle_deg": VIEW_ANGLE_DEG,
            "outward": [[0.0, 0.0, 1.0]] * len(truth.points)}
