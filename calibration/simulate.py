"""Simulated measurements from true parameters plus noise (for trace
generation, tests and demos). Pure numerics: the caller passes the generator.
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError


def measure(method: str, robot, xi_true, qm, *, reference_qm=None, noise=None,
            rng: np.random.Generator | None = None, guess=None, mount=(0.0, 0.0)) -> dict:
    """Readings of the channels ``method`` uses at actuator values ``qm (m, n)``.

    noise: channel -> std of one reading (``pose`` takes a number or 4 values).
    """
    noise = noise or {}
    rng = rng or np.random.default_rng()
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    m = qm.shape[0]

    def n(ch, shape):
        s = np.asarray(noise.get(ch, 0.0), dtype=float)
        return rng.normal(size=shape) * s if np.any(s) else np.zeros(shape)

    if method == "sm-full-pose":
        return {"pose": robot.fk(qm, xi_true) + n("pose", (m, 4))}
    if method == "sm-position":                     # a laser tracker's reflector
        return {"position": robot.fk(qm, xi_true)[:, :3] + n("position", (m, 3))}
    if method in ("sm-distance", "sm-distance-tilt"):
        if reference_qm is None:
            raise CalibrationError(f"{method} needs the reference actuator values")
        X = robot.fk(qm, xi_true)
        ref = robot.fk(np.atleast_2d(reference_qm), xi_true)[0, :3]
        out = {"distance": np.linalg.norm(X[:, :3] - ref, axis=1) + n("distance", m)}
        if method == "sm-distance-tilt" and getattr(robot, "spec", None) is not None:
            from calibration.robots.agebot_pm import gravity_tilt   # a robot file's tool inclinometer

            roll, pitch = gravity_tilt(robot.frames(qm, xi_true)[:, :3, :3], mount)
            out["tilt"] = np.column_stack([roll, pitch]) + n("tilt", (m, 2))
        elif method == "sm-distance-tilt":
            out["tilt"] = X[:, 3] + n("tilt", m)
        return out
    if method in ("sm-self-redundancy", "sm-plane"):
        return {}
    if method in ("pm-ik", "pm-fk"):
        X = robot.fk(qm, xi_true, guess=guess)
        return {"orientation": X + n("orientation", (m, 3))}
    if method == "pm-tilt":
        from calibration.robots.agebot_pm import gravity_tilt, rot_xyz

        X = robot.fk(qm, xi_true, guess=guess)
        roll, pitch = gravity_tilt(rot_xyz(X), mount)
        return {"tilt": np.column_stack([roll, pitch]) + n("tilt", (m, 2))}
    raise CalibrationError(f"unknown method {method!r}")
