"""Pose design at the station: which of the planner's poses to measure, and the
accuracy they will give, before anything is measured.

The planner draws a *pool* of reachable, safe candidate poses (its own sampling,
many more than needed); :func:`pool_model` builds the method's measurement model
over the pool with the readings the current model predicts there, and
:func:`design_poses` chooses the poses by D-optimality (``"optimal"``) or at random
(``"random"``, the old behaviour), with the predicted std of every identifiable
parameter (Cramer-Rao), the observability indices O1 and O3, and the predicted
error of the tool on held-out poses (:mod:`calibration.design`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration import design as dz
from calibration import simulate
from calibration.errors import CalibrationError
from calibration.methods import METHODS, MethodData, build
from calibration.robots.agebot_pm import gravity_tilt
from station.recording.channels import VECTOR_CHANNELS

DESIGNS = ("optimal", "random")

#: std of one reading per solver row channel where the caller gives none: the
#: station's devices (draw-wire 10 um, inclinometer 1.7e-4 rad, a tracker 0.1 mm,
#: the wrist's orientation sensor 1e-3 rad, a touch 0.1 mm, a point on the tool 0.1 mm).
DEFAULT_NOISE = {"distance": 1e-5, "tilt": 1.7e-4, "roll": 1.7e-4, "pitch": 1.7e-4,
                 "x": 1e-4, "y": 1e-4, "z": 1e-4, "phi": 1e-4, "plane": 1e-4,
                 "alpha": 1e-3, "beta": 1e-3, "gamma": 1e-3, "marker": 1e-4}

#: how many candidates the planner draws per pose asked for
POOL_FACTOR = 10


@dataclass(frozen=True)
class Design:
    """A chosen plan and its predicted accuracy.

    fit:       pool indices of the poses to measure, in the order chosen.
    design:    ``"optimal"`` or ``"random"``.
    names:     identifiable parameters; ``std`` their predicted std (Cramer-Rao).
    indices:   ``{"O1": ..., "O3": ..., "condition_number": ...}`` (Sun and Hollerbach).
    heldout:   predicted RMS error of the tool on poses not in the plan
               (``{"what": "position" | "orientation", "rms": value, "unit": "m" | "rad"}``).
    """

    fit: np.ndarray
    design: str
    names: tuple[str, ...]
    std: np.ndarray
    indices: dict
    heldout: dict = field(default_factory=dict)

    def as_record(self) -> dict:
        """JSON-ready summary (trace event, parameter file, report); a figure the plan
        cannot give (a parameter it cannot identify) is None."""
        return {"design": self.design, "poses": int(len(self.fit)),
                "predicted_std": {n: _finite(s) for n, s in zip(self.names, self.std)},
                "observability": {k: _finite(v) for k, v in self.indices.items()},
                "predicted_heldout": {k: _finite(v) if isinstance(v, float) else v
                                      for k, v in self.heldout.items()}}


def _finite(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def row_noise(method: str, noise: dict | None) -> dict:
    """Solver row channel -> std of one reading, from a trace-style ``noise``
    (channel -> std or list) over :data:`DEFAULT_NOISE`."""
    out = dict(DEFAULT_NOISE)
    for ch, v in (noise or {}).items():
        if ch in VECTOR_CHANNELS:
            names = VECTOR_CHANNELS[ch] if method != "sm-distance-tilt" else ("tilt",)
            vals = list(v) if isinstance(v, (list, tuple)) else [v] * len(names)
            out.update({n: float(s) for n, s in zip(names, vals) if s})
        elif not isinstance(v, (list, tuple)) and v:
            out[ch] = float(v)
    return out


def pool_model(method: str, robot, x_plan, qm, *, reference_qm=None, group=None,
               components=None, mount=(0.0, 0.0), plane=None, distance_zero="exact"):
    """The measurement model of ``method`` over the candidate poses ``qm``, with the
    readings the planning model ``x_plan`` predicts there (so the model fits them).
    sm-markers: ``x_plan`` carries the points on the tool after the robot's parameters
    (``marker{j}_x, _y, _z``, the method's own)."""
    mi = METHODS[method]
    x_all = np.asarray(x_plan, dtype=float)
    x_plan = x_all[:robot.n_params]
    points = x_all[robot.n_params:] if method == "sm-markers" else None
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    if getattr(robot, "spec", None) is not None:     # a robot file's serial arm
        channels = readings(robot, method, x_plan, qm, reference_qm=reference_qm, mount=mount,
                            points=points)
    else:
        channels = simulate.measure(method, robot, x_plan, qm, reference_qm=reference_qm,
                                    mount=mount)
    if method == "pm-fk" and components:
        idx = [("alpha", "beta", "gamma").index(c) for c in components]
        channels = {"orientation": channels["orientation"][:, idx]}
    data = MethodData(qm=qm, channels=channels, group=group, reference_qm=reference_qm,
                      components=tuple(components) if components else None,
                      distance_zero=distance_zero if "distance" in channels else "exact")
    extras = []
    options = {}
    if method == "sm-plane":
        if plane is None:
            raise CalibrationError("sm-plane's pose design needs the plane")
        extras = list(plane)
        options["plane_given"] = True
    elif method == "pm-tilt":
        extras = list(mount)
    elif method == "sm-markers":
        extras = list(points)
    if mi.kind == "parallel-wrist":
        options["start"] = "nominal"
    return build(method, robot, data, np.r_[x_plan, extras], **options)


def readings(robot, method: str, xi, qm, *, reference_qm=None, mount=(0.0, 0.0),
             points=None) -> dict:
    """The noise-free readings of ``method``'s channels of the robot file's ``robot``
    with parameters ``xi`` at actuator values ``qm (m, n)`` (none for the touching
    methods: their constraint is the measurement); sm-markers: ``points`` on the tool
    (``(M, 3)`` in the tip link's frame, or flat) in the instrument's frame."""
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    if method == "sm-markers":
        u = np.asarray(points if points is not None else (), dtype=float).reshape(-1, 3)
        if not len(u):
            raise CalibrationError("sm-markers' readings need the points on the tool")
        T = robot.frames(qm, np.asarray(xi, dtype=float)[:robot.n_params])
        return {"markers": T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], u)}
    if method in ("sm-full-pose", "sm-position"):
        X = robot.fk(qm, xi)
        return {"position": X[:, :3]} if method == "sm-position" else {"pose": X}
    if method in ("sm-distance", "sm-distance-tilt"):
        if reference_qm is None:
            raise CalibrationError(f"{method} needs the reference actuator values")
        T = robot.frames(qm, xi)
        p_ref = robot.frames(np.atleast_2d(reference_qm), xi)[0, :3, 3]
        out = {"distance": np.linalg.norm(T[:, :3, 3] - p_ref, axis=1)}
        if method == "sm-distance-tilt":
            out["tilt"] = np.column_stack(gravity_tilt(T[:, :3, :3], mount))
        return out
    return {}


def heldout_map(robot, model, info: dz.PoseInformation, qm_out):
    """``(J, what, unit)``: the linear map from the identifiable robot parameters'
    errors to the tool's position (orientation, for a wrist) at the poses ``qm_out``,
    ``J: (poses, 3, L)`` over ``info``'s columns (zero for non-robot parameters);
    None where it cannot be formed."""
    nr = robot.n_params
    cols = [k for k, j in enumerate(info.columns) if j < nr]
    if len(qm_out) == 0 or not cols:
        return None
    coords = tuple(robot.coords)
    if "x" in coords:
        rows, what, unit = [coords.index(c) for c in ("x", "y", "z")], "position", "m"
    else:
        rows, what, unit = list(range(len(coords))), "orientation", "rad"
    Jr = dz.fk_jacobian(robot.fk, np.atleast_2d(qm_out), model.x0[:nr], info.columns[cols])
    J = np.zeros((Jr.shape[0], len(rows), len(info.columns)))
    J[:, :, cols] = Jr[:, rows, :]
    return J, what, unit


def heldout_rms(J: np.ndarray, cov: np.ndarray) -> float:
    """RMS over poses of the predicted norm of the tool's error ``J dx``."""
    var = np.einsum("mrl,lk,mrk->m", J, cov, J)
    return float(np.sqrt(np.mean(np.maximum(var, 0.0))))


def design_poses(model, count: int, *, design: str = "optimal", rng=None, noise=None,
                 group=None, robot=None, target=None, heldout_qm=None) -> Design:
    """Choose ``count`` poses of the pool ``model`` (see :func:`pool_model`).

    noise:  solver row channel -> std (:func:`row_noise`).
    group:  poses measured together (sm-self-redundancy pairs): ``count`` counts groups.
    target: None, or ``(name, std)``: poses are added (each the most informative) until
            the predicted std of parameter ``name`` is at most ``std``; name ``"heldout"``:
            the predicted held-out RMS error of the tool (m, or rad for a wrist).
    robot/heldout_qm: for the predicted held-out error (poses not in the plan)."""
    if design not in DESIGNS:
        raise CalibrationError(f"unknown design {design!r} (known: {', '.join(DESIGNS)})")
    info = dz.pose_information(model, model.x0, noise or DEFAULT_NOISE, group=group)
    if count > info.size:
        raise CalibrationError(f"{count} poses asked, only {info.size} candidates in the pool")
    if design == "optimal":
        chosen = dz.d_optimal(info, count)
    else:
        rng = rng or np.random.default_rng(0)
        chosen = rng.choice(info.size, size=count, replace=False)
    hm = None
    if robot is not None and heldout_qm is not None:
        hm = heldout_map(robot, model, info, heldout_qm)
    return _predicted(info, chosen, design, target, hm)


def _predicted(info: dz.PoseInformation, chosen, design: str, target, hm) -> Design:
    """Grow ``chosen`` to meet ``target`` (if any) and predict its accuracy."""
    if target is not None:
        chosen = dz.grow_until(info, _target(target, info, hm), start=chosen)
    held = {}
    if hm is not None:
        J, what, unit = hm
        held = {"what": what, "unit": unit, "rms": heldout_rms(J, dz.covariance(info, chosen))}
    return Design(info.poses(chosen), design, info.names, dz.cramer_rao(info, chosen),
                  dz.observability(info, chosen), held)


def _target(target, info: dz.PoseInformation, hm):
    """``met(cov)`` for a ``(name, std)`` target; a target the whole pool cannot meet is
    refused at once, naming the best the pool predicts."""
    name, limit = target
    if name == "heldout":
        if hm is None:
            raise CalibrationError("a held-out accuracy target needs held-out poses")
        best = heldout_rms(hm[0], dz.covariance(info, np.arange(info.size)))
        if best > limit:
            raise CalibrationError(
                f"--target-std {limit:g}: even all {info.size} candidate poses predict a "
                f"held-out {hm[1]} error of {best:.3g} {hm[2]}; widen the workspace or relax "
                f"the target")
        return lambda cov: heldout_rms(hm[0], cov) <= limit
    if name not in info.names:
        raise CalibrationError(f"--target-std {name}: not an identifiable parameter here "
                               f"(identifiable: {', '.join(info.names)})")
    j = info.names.index(name)
    best = float(np.sqrt(dz.covariance(info, np.arange(info.size))[j, j]))
    if best > limit:
        raise CalibrationError(f"--target-std {name}={limit:g}: even all {info.size} candidate "
                               f"poses predict a std of {best:.3g}; widen the workspace or "
                               f"relax the target")
    return lambda cov: np.sqrt(cov[j, j]) <= limit


def choose(method: str, robot, x_plan, candidates, n_fit: int, *, measured=(), design="optimal",
           rng=None, noise=None, reference_qm=None, components=None, mount=(0.0, 0.0),
           plane=None, target=None, heldout_qm=None,
           distance_zero="exact") -> tuple[np.ndarray, Design]:
    """A session's next poses: ``n_fit`` of the ``candidates`` (actuator values the planner
    drew, reachable and inside the envelope), chosen at the current model ``x_plan`` given
    the poses already ``measured`` (sequential design: each new pose is worth most where
    the measured ones say least). Returns the chosen candidates' indices and the
    prediction for the measured and chosen poses together."""
    candidates = np.atleast_2d(np.asarray(candidates, dtype=float))
    measured = np.asarray(measured, dtype=float).reshape(-1, candidates.shape[1])
    pool = np.vstack([measured, candidates])
    model = pool_model(method, robot, x_plan, pool, reference_qm=reference_qm,
                       components=components, mount=mount, plane=plane,
                       distance_zero=distance_zero)
    info = dz.pose_information(model, model.x0, noise or DEFAULT_NOISE)
    k = len(measured)
    want = k + n_fit
    if want > info.size:
        raise CalibrationError(f"{n_fit} poses asked, only {len(candidates)} candidates")
    if design == "optimal":
        chosen = dz.d_optimal(info, want, fixed=range(k))
    else:
        rng = rng or np.random.default_rng(0)
        chosen = np.r_[np.arange(k), k + rng.choice(len(candidates), n_fit, replace=False)]
    hm = heldout_map(robot, model, info, heldout_qm) if heldout_qm is not None else None
    plan = _predicted(info, chosen, design, target, hm)
    return plan.fit[plan.fit >= k] - k, plan


def design_text(record: dict, units=None) -> str:
    """One line for people about a plan's design (:meth:`Design.as_record`)."""
    from station.outputs.units import MM_DEG

    units = units or MM_DEG
    o = {k: (float("nan") if v is None else v) for k, v in
         (record.get("observability") or {}).items()}
    text = (f"{'D-optimal' if record.get('design') == 'optimal' else 'random'} poses "
            f"(observability O1 {o.get('O1', float('nan')):.3g}, O3 {o.get('O3', float('nan')):.3g})")
    held = record.get("predicted_heldout") or {}
    if held.get("rms") is None and "what" in held:
        text += f"; the plan cannot predict the held-out {held['what']} error (too few poses)"
    elif "rms" in held:
        text += (f"; predicted held-out {held['what']} error "
                 f"{units.text(held['rms'], held['unit'], '.3g')} RMS")
    return text
