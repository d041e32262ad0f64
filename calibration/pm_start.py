"""Robust start values for the PM calibration (report section 10).

The report's nominal PM is far from the real one (a2 60 % off, gear ratios
10-15 %): at the nominal geometry the rods cannot even reach their platform
points at ``X = 0``, so neither the IK nor the FK of the nominal model is
defined for the measured poses, and Gauss-Newton on FK residuals from there
has nothing to start from. The start is found in three steps:

1. **Reachable geometry** (:func:`feasible_start`): the rod length ``l`` is
   moved to the value that best explains the measured actuator values at the
   guessed orientations, ``l^2 = mean(h^2 + (D_z - q)^2)`` (h: horizontal
   distance from base point to platform point), and at least 2 % above the
   largest h, so that the IK exists for every pose.
2. **Joint-space fit with unknown orientations** (:class:`ImplicitPoses`): the
   closure equations ``F^-1(X_j, xi) = Qm_j`` in actuator units (3 rows per
   pose, eq. 106 divided by K: see :mod:`calibration.methods.pm_ik` for why not
   in joint space) plus the readings (measured Euler components, or inclinometer
   roll and pitch), with every pose's full orientation ``X_j`` an unknown
   next to xi. Only the IK is needed, which is defined wherever the rods
   reach; there is no assembly mode to lose. The same solver runs it.
3. The method's own (FK-based) refinement starts from that ``xi`` with each
   pose's FK started at its fitted ``X_j`` (the caller does this).

Step 2 is dense in the poses (3 unknown angles each: the normal matrix grows with
the square of their number, the work with its cube). Beyond :data:`START_SUBSET`
poses it is run on that many poses spread over the measured orientations
(farthest-point selection), and every pose's own angles are then fitted with
``xi`` held, pose by pose (:func:`fit_orientations`, 3 unknowns each): the start
costs time and memory linear in the number of poses. Up to
:data:`START_SUBSET` poses nothing changes.

Where step 2 does not converge from the far nominal (pm-tilt on wrists far from
the report's: the yaw is unseen and the fit drifts along the model's scale), it is
grown from home outwards as a session grows its box (:func:`_staged_fit`): the
poses whose readings are within 6, 10, 16 deg, then all, each stage started at the
last.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.pm_common import (COMPONENTS, orientation_channel, parse_components,
                                           wrap)
from calibration.model import MeasurementModel
from calibration.robots.agebot_pm import tilt_jacobian

REACH_MARGIN = 1.02
START_SUBSET = 60        # poses of the joint-space start fit (module doc)
STAGES_DEG = (6.0, 10.0, 16.0)   # staged fit (fallback): reading bounds of the stages
MIN_STAGE_POSES = 10


@dataclass(frozen=True)
class StartResult:
    """x: ``(N,)`` start values (robot parameters, then mount for tilt);
    X: ``(m, 3)`` fitted orientation of each pose; result: the joint-space fit."""

    x: np.ndarray
    X: np.ndarray
    result: object


def feasible_start(robot, qm, X_guess, nominal) -> np.ndarray:
    """``nominal`` with the rod length ``l`` moved so that the IK reaches every
    pose at orientations ``X_guess (m, 3)`` (step 1 of the module doc)."""
    xi = np.array(nominal, dtype=float)
    B, _, _, _ = robot._geometry(xi)
    _, D = robot.platform_points(X_guess, xi)
    d = D - B[None]
    h2 = d[..., 0] ** 2 + d[..., 1] ** 2
    q = robot.joints(qm, xi)
    l_fit = np.sqrt(np.mean(h2 + (D[..., 2] - q) ** 2))
    xi[robot.index("l")] = max(l_fit, REACH_MARGIN * np.sqrt(h2.max()))
    return xi


def guess_orientations(readings: np.ndarray, comps) -> np.ndarray:
    """Start orientations ``(m, 3)`` from the readings ``(m, k)``: the measured
    components, 0 for the others; for an inclinometer (``comps`` None),
    ``alpha ~ roll``, ``beta ~ pitch``, ``gamma = 0``."""
    readings = np.asarray(readings, dtype=float)
    X = np.zeros((readings.shape[0], 3))
    if comps is None:
        X[:, :2] = readings[:, :2]
    else:
        for j, c in enumerate(comps):
            X[:, COMPONENTS.index(c)] = readings[:, j]
    return X


class ImplicitPoses(MeasurementModel):
    """Joint-space closure with unknown orientations (step 2 of the module doc).

    Parameters: the robot's 10 (then ``mount_x, mount_y`` for an inclinometer),
    then ``alpha_j, beta_j, gamma_j`` of every pose. Rows per pose: ``q1, q2, q3``
    (``c * (Qm_j - F^-1(X_j, xi))``) then the readings (rad). The constant
    ``c = k_start / lever`` (``lever``: mean slider travel per radian at the start)
    expresses the actuator rows in radian-equivalents, so that the solver's single
    pooled sigma (eq. 51) weighs both kinds of rows alike; being constant, it keeps
    the scale and height invariance of the actuator rows.
    """

    method = "pm-start"
    default_damping = 1e-4

    def __init__(self, robot, qm, x_robot, X_guess, *, readings, comps=None, tilt=False):
        self.robot, self.qm, self.tilt = robot, np.asarray(qm, dtype=float), tilt
        m = self.qm.shape[0]
        self.n_poses, self.nr = m, robot.n_params
        self.ne = len(x_robot)  # robot parameters (+ mount)
        self.readings = np.asarray(readings, dtype=float)
        self.comp_idx = [COMPONENTS.index(c) for c in comps] if not tilt else []
        pose_names = tuple(f"{c}_{j}" for j in range(m) for c in COMPONENTS)
        extra = ("mount_x", "mount_y") if tilt else ()
        self.names = tuple(robot.param_names) + extra + pose_names
        self.x0 = np.concatenate([x_robot, np.asarray(X_guess, dtype=float).reshape(-1)])
        self.nominal = self.x0.copy()
        xi0 = np.asarray(x_robot[:self.nr], dtype=float)
        lever = np.mean(np.linalg.norm(robot.ik_x_jacobian(X_guess, xi0), axis=2))
        self.row_scale = np.abs(xi0[7:10]) / lever  # (3,)
        meas = ("roll", "pitch") if tilt else tuple(comps)
        self.channels = ("q1", "q2", "q3") + meas
        self.row_channel = np.tile(np.arange(len(self.channels)), m)

    def split(self, x):
        return x[:self.ne], x[self.ne:].reshape(-1, 3)

    def evaluate(self, x):
        xe, X = self.split(x)
        xi = xe[:self.nr]
        m, nr, ne = self.n_poses, self.nr, self.ne
        k = xi[7:10][None, :, None]
        qm_pred = self.robot.ik_actuators(X, xi)  # UnreachablePose (a CalibrationError) outside
        c = self.row_scale[None, :, None]
        rq = (self.qm - qm_pred) * self.row_scale
        Wq_xi = self.robot.psi_iku(X, xi, qm_pred) / k * c
        Wq_X = self.robot.ik_x_jacobian(X, xi) / k * c
        if self.tilt:
            t, dT_dX, dT_dm = tilt_jacobian(X, xe[nr:ne])
            rm = wrap(self.readings - t)
            Wm_e = np.concatenate([np.zeros((m, 2, nr)), dT_dm], axis=2)
            Wm_X = dT_dX
        else:
            rm = wrap(self.readings - X[:, self.comp_idx])
            Wm_e = np.zeros((m, len(self.comp_idx), ne))
            Wm_X = np.broadcast_to(np.eye(3)[self.comp_idx], (m, len(self.comp_idx), 3))
        p = 3 + rm.shape[1]
        W = np.zeros((m, p, ne + 3 * m))
        W[:, :3, :nr] = Wq_xi
        W[:, 3:, :ne] = Wm_e
        j = np.arange(m)
        for c in range(3):
            W[j, :3, ne + 3 * j + c] = Wq_X[:, :, c]
            W[j, 3:, ne + 3 * j + c] = Wm_X[:, :, c]
        r = np.concatenate([rq, rm], axis=1)
        return r.reshape(-1), W.reshape(m * p, -1)


def spread_subset(X, k: int) -> np.ndarray:
    """Indices of ``k`` of the orientations ``X (m, 3)`` spread over them (farthest-point
    selection from the first; ``O(m k)``), sorted."""
    X = np.asarray(X, dtype=float)
    m = X.shape[0]
    if m <= k:
        return np.arange(m)
    chosen = [0]
    d = np.max(np.abs(X - X[0]), axis=1)
    for _ in range(k - 1):
        j = int(np.argmax(d))
        chosen.append(j)
        d = np.minimum(d, np.max(np.abs(X - X[j]), axis=1))
    return np.sort(np.array(chosen))


def fit_orientations(model: "ImplicitPoses", xe, X0, *, iterations: int = 50,
                     tol: float = 1e-12) -> np.ndarray:
    """Each pose's orientation ``(m, 3)`` for the parameters ``xe`` held fixed: the rows of
    ``model`` (actuators and readings, same weights) per pose, 3 unknowns each, by
    Gauss-Newton with step halving where a rod would not reach; linear in the poses."""
    X = np.array(X0, dtype=float)
    m = X.shape[0]
    xi = np.asarray(xe[:model.nr], dtype=float)
    mount = xe[model.nr:model.ne]

    def rows(X):
        with np.errstate(invalid="ignore"):
            qm_pred = model.robot.ik_actuators(X, xi, strict=False)
        rq = (model.qm - qm_pred) * model.row_scale
        Jq = model.robot.ik_x_jacobian(X, xi) / xi[7:10][None, :, None] * model.row_scale[None, :, None]
        if model.tilt:
            t, dT_dX, _ = tilt_jacobian(X, mount)
            rm, Jm = wrap(model.readings - t), dT_dX
        else:
            rm = wrap(model.readings - X[:, model.comp_idx])
            Jm = np.broadcast_to(np.eye(3)[model.comp_idx], (m, len(model.comp_idx), 3))
        r = np.concatenate([rq, rm], axis=1)
        return r, np.concatenate([Jq, Jm], axis=1)

    r, J = rows(X)
    cost = np.sum(r * r, axis=1)
    for _ in range(iterations):
        ok = np.isfinite(cost)
        A = np.einsum("mpi,mpj->mij", J[ok], J[ok]) + 1e-12 * np.eye(3)
        g = np.einsum("mpi,mp->mi", J[ok], r[ok])
        step = np.zeros_like(X)
        step[ok] = np.linalg.solve(A, g[..., None])[..., 0]
        if np.max(np.abs(step)) < tol:
            break
        t = np.ones(m)
        for _ in range(30):
            Xn = X + t[:, None] * step
            rn, Jn = rows(Xn)
            cn = np.sum(rn * rn, axis=1)
            worse = ~(np.isfinite(cn) & (cn <= cost * (1 + 1e-12) + 1e-300))
            if not np.any(worse & ok):
                break
            t = np.where(worse & ok, t / 2, t)
        better = np.isfinite(cn) & (cn <= cost * (1 + 1e-12) + 1e-300)
        X[better], r[better], J[better], cost[better] = Xn[better], rn[better], Jn[better], cn[better]
    return X


def _staged_fit(model: ImplicitPoses, opts):
    """The joint-space fit grown from the poses nearest home outwards (readings within
    :data:`STAGES_DEG`, then all), each stage started at the last: where the fit of
    every pose at once from the far nominal does not converge (pm-tilt, whose yaw is
    unseen, drifts along the scale of the model). ``(model, result)`` of the last
    stage, or None when a stage fails."""
    from calibration.solver import solve

    size = np.max(np.abs(model.readings), axis=1)
    xe, X = model.split(model.x0)
    X = X.copy()
    out = None
    for lim in [np.radians(d) for d in STAGES_DEG] + [np.inf]:
        sel = size <= lim
        if lim != np.inf and (sel.sum() < MIN_STAGE_POSES or sel.all()):
            continue
        mk = ImplicitPoses(model.robot, model.qm[sel], xe, X[sel], readings=model.readings[sel],
                           comps=[COMPONENTS[i] for i in model.comp_idx] or None,
                           tilt=model.tilt)
        try:
            res = solve(mk, opts)
        except CalibrationError:
            return None
        if not np.all(np.isfinite(res.x)):
            return None
        xe, X[sel] = mk.split(res.x)
        out = (mk, res)
    return out


def robust_start_detail(robot, method_data, nominal, components=None, *,
                        options=None, subset: int = START_SUBSET) -> StartResult:
    """Start values and per-pose orientations (module doc). ``method_data`` is a
    :class:`calibration.methods.MethodData` with channel ``orientation`` (components
    ``components``) or ``tilt`` (roll, pitch; then ``nominal`` has 12 values)."""
    from calibration.solver import SolverOptions, solve

    qm = np.atleast_2d(np.asarray(method_data.qm, dtype=float))
    m = qm.shape[0]
    tilt = "tilt" in method_data.channels and "orientation" not in method_data.channels
    nominal = np.asarray(nominal, dtype=float)
    if tilt:
        readings = np.asarray(method_data.channels["tilt"], dtype=float).reshape(m, 2)
        comps = None
        X0 = guess_orientations(readings, None)
    else:
        comps = parse_components(components if components is not None
                                 else method_data.components)
        readings = orientation_channel(method_data.channels, comps, "pm start")
        X0 = guess_orientations(readings, comps)
    nr = robot.n_params
    xe = nominal.copy()
    xe[:nr] = feasible_start(robot, qm, X0, nominal[:nr])
    every = ImplicitPoses(robot, qm, xe, X0, readings=readings, comps=comps, tilt=tilt)
    pick = spread_subset(X0, subset)
    model = every if len(pick) == m else ImplicitPoses(
        robot, qm[pick], xe, X0[pick], readings=readings[pick], comps=comps, tilt=tilt)
    every.row_scale = model.row_scale     # the same weights for every pose's own fit
    # recheck=False: the per-pose angles must not meet the statistical test at the
    # solution (a weakly seen gamma_j reset to its guess can leave the reachable set);
    # q3_off, k3 are structurally dependent and dropped before iterating;
    # hold_damping: the damping, once raised, keeps the joint fit from drifting
    # along the scale of the model (pm-fk on alpha alone from the report's nominal
    # otherwise converges to every length 381 times the truth's)
    opts = options or SolverOptions(epsilon=1e-9, max_iter=300, recheck=False,
                                    hold_damping=True)
    res = solve(model, opts)
    if not res.converged:       # grow the fitted region as a session grows its box
        staged = _staged_fit(model, opts)
        if staged is not None:
            model, res = staged
    if not np.all(np.isfinite(res.x)):
        raise CalibrationError("the PM start-value fit failed: " + res.message)
    xe, X = model.split(res.x)
    if len(X) < m:              # every pose's own angles, xi held (module doc)
        X0 = X0.copy()
        X0[pick] = X
        X = fit_orientations(every, xe, X0)
    return StartResult(xe.copy(), X.copy(), res)


def robust_start(robot, method_data, nominal, components=None) -> np.ndarray:
    """Start values ``x_start`` of the PM parameters (module doc), from the report's
    (possibly far) nominal values: 10 robot parameters, plus the mount for tilt data."""
    return robust_start_detail(robot, method_data, nominal, components).x
