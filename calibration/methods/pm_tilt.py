"""pm-tilt: pm-fk with a physical dual-axis inclinometer on the platform.

The sensor reads the direction of gravity in its own frame (roll, pitch of
:func:`calibration.robots.inclinometer.gravity_tilt`), not Euler angles, and sits
on the platform with a small unknown rotation ``R_mount = Rx(mount_x) Ry(mount_y)``.
Trace channel ``tilt`` ``(m, 2)`` = (roll, pitch), rad; model channels ``roll``,
``pitch``. Parameters: the robot's 10, then ``mount_x, mount_y``.

Rows per pose: ``tilt_M - gravity_tilt(R(F(Qm, xi)), mount)`` (wrapped); observation
matrix ``dT/dX Psi^PKU`` for xi and ``dT/dmount`` for the mount
(:func:`calibration.robots.inclinometer.tilt_jacobian`). A rotation about the
vertical is invisible to the sensor (yaw is lost, two rows per pose); with it,
``q3_off, k3`` stay compensated (eqs. 112-113) as in pm-fk.

**The heading is not identified.** Turning the platform about the vertical leaves
every reading unchanged, at every pose on its own. No single parameter is
unidentifiable: the model's rigid structure (triangles, rods) ties the heading to the
tilt and so fixes it, but weakly: with a session's 24 poses its std is 0.2-0.3 deg,
2-3 actuator units of the IK over +-15 deg, while the IK without the heading is
within ~0.2 units. The method therefore claims the IK only up to a rotation about
the vertical (:func:`ik_modulo_heading`) and states the heading's std
(:func:`heading_uncertainty`, :meth:`Tilt.unidentified_directions`;
docs/methods.md).
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import MethodData
from calibration.methods.base import channel
from calibration.methods.pm_common import (COMPENSATION_NOTE, STARTS, ModeKeepingFK,
                                              PMMethod, wrap)
from calibration.pm_start import guess_orientations, robust_start_detail
from calibration.robots.agebot_pm import euler_rates, euler_xyz, rot_xyz, tilt_jacobian

#: box (deg) over which the heading's std and the IK are stated (the station's +-15 deg check)
HEADING_BOX_DEG = 15.0
HEADING_NOTE = (
    "pm-tilt does not identify the platform's heading (its rotation about the vertical): "
    "a dual-axis inclinometer reads only the direction of gravity, which no rotation about "
    "the vertical changes. Only the model's rigid structure ties the heading to the tilt, "
    "weakly, and an error the model does not describe (a base turned on its mount) would "
    "shift it unseen. The calibrated IK puts the platform at the commanded tilt; its "
    "heading may be off by the std stated with it (the table, the report and the parameter "
    "file's not_identified), often one to three actuator units. "
    "Calibrate with pm-fk (an orientation sensor that reads the heading) where the heading "
    "matters.")


class Tilt(PMMethod):
    method = "pm-tilt"
    extra_names = ("mount_x", "mount_y")
    notes = (COMPENSATION_NOTE, HEADING_NOTE)

    def __init__(self, robot, qm, measured: dict, nominal, *, start: str = "robust",
                 start_options=None):
        super().__init__(robot, qm, nominal)
        if start not in STARTS:
            raise CalibrationError(f"start must be one of {STARTS}, not {start!r}")
        self.T_m = channel(measured, "tilt", self.method, shape=(2,))
        self.start = None
        if start == "robust":
            data = MethodData(self.qm, {"tilt": self.T_m})
            self.start = robust_start_detail(robot, data, self.nominal, options=start_options)
            self.x0, guess = self.start.x.copy(), self.start.X
        else:   # the start's own FK, from the readings' guess (its heading 0): the
            # heading, which the readings do not give, can lie far from 0 (a box centred
            # on a model's heading at home, station.planning.wrist_plan)
            guess = guess_orientations(self.T_m, None)
            try:
                guess = robot.fk(self.qm, self.x0[:self.nr], guess=guess)
            except CalibrationError:
                pass
        self.fk = ModeKeepingFK(robot, self.qm, guess)
        self._channels(("roll", "pitch"), [0, 1])
        self.noise_groups = (self.channels,)  # one inclinometer's two axes

    def operator_notes(self, x=None) -> tuple[str, ...]:
        return super().operator_notes(x) + (HEADING_NOTE,)

    def unidentified_directions(self, result) -> list[dict]:
        """What the fit ``result`` does not identify, for the parameter file's
        ``not_identified``: the heading, with its std over +-:data:`HEADING_BOX_DEG`."""
        u = heading_uncertainty(self.robot, result.x[:self.nr], result.covariance,
                                result.covariance_names)
        return [{"direction": "heading",
                 "statement": ("rotation of the platform about the vertical: not seen by the "
                               "inclinometer, fixed only weakly by the model's structure; the "
                               "calibrated IK is claimed up to this rotation"),
                 "box_deg": HEADING_BOX_DEG, "std_rad": u["heading_std"],
                 "ik_std": u["ik_std"], "ik_std_modulo_heading": u["ik_std_modulo_heading"]}]

    def evaluate(self, x):
        xi, mount = x[:self.nr], x[self.nr:]
        X = self.fk(xi)
        t, dT_dX, dT_dm = tilt_jacobian(X, mount)
        r = wrap(self.T_m - t)
        W = np.concatenate([dT_dX @ self.robot.psi_pku(X, xi, self.qm), dT_dm], axis=2)
        return r.reshape(-1), W.reshape(-1, len(self.names))


def heading_grid(box_deg: float = HEADING_BOX_DEG) -> np.ndarray:
    """Orientations ``(343, 3)``: the 7^3 grid of +-``box_deg`` (deg)."""
    g = np.radians(np.linspace(-box_deg, box_deg, 7))
    return np.array(np.meshgrid(g, g, g)).reshape(3, -1).T


def heading_rate(robot, X, xi) -> np.ndarray:
    """``dQm/dphi (m, 3)``: actuator change per rad of a rotation ``Rz(phi) R`` of the
    platform about the vertical, at orientations ``X (m, 3)`` of the model ``xi``."""
    dX = np.linalg.solve(euler_rates(X), np.broadcast_to([0.0, 0.0, 1.0], (len(X), 3))[..., None])[..., 0]
    return np.einsum("mij,mj->mi", robot.ik_x_jacobian(X, xi), dX) / np.asarray(xi[7:10])


def heading_uncertainty(robot, xi, covariance, names, box_deg: float = HEADING_BOX_DEG) -> dict:
    """Worst std over the +-``box_deg`` grid of the calibrated model ``xi``'s IK
    (``covariance`` over ``names``; parameters not in ``names`` held): ``heading_std``
    (rad) of the heading the IK gives, ``ik_std`` (actuator units) of the IK, and
    ``ik_std_modulo_heading`` of the IK with each pose's heading taken out."""
    X = heading_grid(box_deg)
    xi = np.asarray(xi, dtype=float)
    dQ = robot.psi_iku(X, xi) / xi[7:10][None, :, None]  # dQm/dxi at fixed X (m, 3, n)
    cols = [robot.param_names.index(n) for n in names if n in robot.param_names]
    keep = [i for i, n in enumerate(names) if n in robot.param_names]
    C = np.asarray(covariance, dtype=float)[np.ix_(keep, keep)]
    J = dQ[..., cols]
    h = heading_rate(robot, X, xi)
    Jh = np.einsum("mi,mik->mk", h, J) / np.einsum("mi,mi->m", h, h)[:, None]
    Jp = J - h[:, :, None] * Jh[:, None, :]  # the IK's change that no heading explains
    var = lambda A: np.einsum("...k,kl,...l->...", A, C, A)  # noqa: E731
    return {"heading_std": float(np.sqrt(var(Jh).max())),
            "ik_std": float(np.sqrt(var(J).max())),
            "ik_std_modulo_heading": float(np.sqrt(var(Jp).max()))}


def ik_modulo_heading(robot, X, x_cal, x_true, iterations: int = 6):
    """How the calibrated IK ``x_cal`` drives the true wrist ``x_true`` at orientations
    ``X (m, 3)``, up to the heading that pm-tilt does not identify: ``(error (m,),
    heading (m,))``, per orientation the worst actuator difference between the
    calibrated IK at ``X`` and the true IK at ``Rz(heading) R(X)``, with the heading
    (rad) that brings them closest (least squares over the three actuators)."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    Qc = robot.ik_actuators(X, x_cal)
    R = rot_xyz(X)
    phi = np.zeros(len(X))
    for k in range(iterations + 1):
        c, s = np.cos(phi), np.sin(phi)
        Rz = np.zeros((len(X), 3, 3))
        Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
        Xp = euler_xyz(Rz @ R)
        d = Qc - robot.ik_actuators(Xp, x_true)
        if k < iterations:  # Gauss-Newton on the heading
            h = heading_rate(robot, Xp, x_true)
            phi = phi + np.einsum("mi,mi->m", h, d) / np.einsum("mi,mi->m", h, h)
    return np.abs(d).max(axis=1), phi
