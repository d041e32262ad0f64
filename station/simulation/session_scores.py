"""A simulated session scored against its truth (:func:`station.simulation.sessions.
run_session`), in the frame the session captured: the normalized errors of its
calibrated parameters and their reported correlation, the tool's error, the excursion
outside the planned box, the draw-wire's offset; :func:`summary` pools many sessions and
:func:`d2_interval` is the range an honest std gives their ``d2``."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from calibration import planning
from calibration.errors import CalibrationError
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import get_robot
from drivers.sim.truth import SimTruth
from station.simulation.serial_sessions import serial_errors


@dataclass
class SessionScore:
    """One scored session.

    completed: the session ran to its parameter file; ``error`` says why not, and
               ``refused`` whether that was the station's named refusal (a
               :class:`~calibration.errors.StationError`: safe, nothing written) rather
               than a crash.
    names, z:  the calibrated (identifiable) parameters and their error / reported std
               (angles compared modulo 2 pi).
    excursion: largest distance of a visited pose (true pose, from the trace's ``qm``)
               outside the planned workspace box, per coordinate (m or rad).
    heldout:   the session's held-out validation, channel -> RMS after calibration.
    tool_error: RMS over poses drawn in the method's whole box of the distance between
               the tool position the calibrated model puts there and the true one
               (captured frame; m).
    corr, dof: the reported correlation of the ``z`` (from the result's covariance) and
               the fewest degrees of freedom of a channel's estimated sigma (inf where
               every sigma was stated): ``d2`` is ``z^T corr^-1 z``, what an honest std
               makes chi-square-like whatever the correlation (:func:`d2_interval`).
    """

    seed: int
    robot: str
    method: str
    completed: bool
    error: str = ""
    refused: bool = False
    names: list[str] = field(default_factory=list)
    z: np.ndarray = field(default_factory=lambda: np.zeros(0))
    excursion: dict = field(default_factory=dict)
    poses: int = 0
    skipped: int = 0
    events: dict = field(default_factory=dict)
    offset: dict = field(default_factory=dict)
    heldout: dict = field(default_factory=dict)
    tool_error: float = math.nan
    corr: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    dof: float = math.inf

    @property
    def worst(self) -> float:
        return float(np.max(np.abs(self.z))) if self.z.size else math.nan

    @property
    def whitened(self) -> np.ndarray:
        """``L^-1 z`` with ``corr = L L^T``: independent errors of unit variance for an
        honest std (one session's ``z`` move together: one data set)."""
        if not self.z.size:
            return self.z
        w, v = np.linalg.eigh(self.corr)           # symmetric inverse square root:
        w = np.clip(w, 1e-15 * w.max(), None)      # stable where columns nearly coincide
        return (v / np.sqrt(w)) @ v.T @ self.z

    @property
    def d2(self) -> float:
        """``z^T corr^-1 z``: chi-square on ``len(z)`` for an honest std and stated
        sigma; :func:`d2_interval` takes the estimated sigma's ``dof`` in."""
        w = self.whitened
        return float(w @ w)


def correlation(result, names) -> np.ndarray:
    """The reported correlation matrix of ``result``'s parameters ``names``."""
    idx = [list(result.covariance_names).index(n) for n in names]
    c = np.asarray(result.covariance, dtype=float)[np.ix_(idx, idx)]
    d = np.sqrt(np.diag(c))
    return c / np.outer(d, d)


def d2_interval(ks, dofs, alpha: float = 0.01, draws: int = 200_000,
                seed: int = 0) -> tuple[float, float]:
    """The two-sided ``alpha`` interval of the sum of sessions' ``d2`` for an honest std:
    a session with ``k`` parameters and sigma estimated on ``dof`` degrees of freedom has
    ``d2 = (nu - 2) / nu * chi2_k / (chi2_nu / nu)`` (the reported std carries the
    ``sqrt(nu / (nu - 2))`` of the sigma's own uncertainty, so its mean is ``k``;
    ``dof`` inf: chi2_k). The fewest channel dof makes the interval the widest.
    Seeded Monte Carlo of the sum."""
    from calibration.solver.weighting import MIN_DOF

    rng = np.random.default_rng(seed)
    total = np.zeros(draws)
    for k, dof in zip(ks, dofs):
        x = rng.chisquare(k, draws)
        if math.isfinite(dof):
            nu = max(float(dof), MIN_DOF)
            x *= (nu - 2.0) / rng.chisquare(nu, draws)
        total += x
    lo, hi = np.quantile(total, [alpha / 2, 1 - alpha / 2])
    return float(lo), float(hi)


def rms_bound(dofs, alpha: float = 0.01, draws: int = 1_000_000, seed: int = 0) -> float:
    """What an honest std's error/std of one parameter exceeds in RMS over sessions
    with probability ``alpha``: one error per session, each sigma estimated on that
    session's ``dofs`` (:func:`d2_interval` with one parameter per session: Student's t
    scaled to unit RMS, heavier-tailed than a normal error: the chi-square bound
    ``sqrt(chi2_k(1 - alpha) / k)``, Bonferroni over 27 parameters at 1 %, is exceeded
    by some parameter of an honest pool of 3 sessions 3, 6.5 and 12.5 % of the time at
    38, 20 and 12 degrees of freedom). Seeded Monte Carlo."""
    k = len(dofs)
    hi = d2_interval([1] * k, list(dofs), 2 * alpha, draws=draws, seed=seed)[1]
    return math.sqrt(hi / k)


def residual_offset(session, truth: SimTruth, state: dict) -> dict:
    """The fit poses' distance residuals at the true parameters (captured frame): their
    mean and its standard error (m) with the zero taken as exact (``distance_off``
    0, the report's model) and with the draw-wire's true zero reading."""
    if "distance" not in session.info.channels or truth.spec is not None:
        return {}
    robot = get_robot(truth.robot)
    ref = truth_in_session_frame(session, truth, state)
    xi = np.array([ref[n] for n in robot.param_names])
    recs = [r for r in session.measured.values() if r.get("use", "fit") == "fit"]
    qm = np.array([r["qm"] for r in recs])
    X = robot.fk(qm, xi)
    p0 = robot.fk(np.atleast_2d(session.reference_qm), xi)[0, :3]
    r = np.array([rec["distance"] for rec in recs]) - np.linalg.norm(X[:, :3] - p0, axis=1)
    se = float(np.std(r, ddof=1) / np.sqrt(len(r)))
    return {"exact": float(np.mean(r)), "reading": float(np.mean(r) - ref.get("distance_off", 0.0)),
            "se": se}


def truth_in_session_frame(session, truth: SimTruth, state: dict) -> dict[str, float]:
    """The truth as the session's calibrated parameters name it: for sm-distance-tilt in
    the base frame captured at the reference; ``distance_off`` from the simulator."""
    robot = get_robot(truth.robot)
    xi = truth.xi()
    if session.method == "sm-distance-tilt":
        xi = reframe_nominal(robot, xi, session.reference_qm)
    out = robot.as_dict(xi)
    if state.get("drawwire_offset") is not None:
        out["distance_off"] = -float(state["drawwire_offset"])
    return out


def tool_error(session, truth: SimTruth, state: dict, count: int = 300) -> float:
    """RMS distance (m) between where the calibrated and the true model put the tool,
    over ``count`` poses drawn (seeded) in the method's whole box by the true IK: how
    well the result holds where the session did not measure. sm-distance-tilt only
    (its 14 parameters identify the tool's position; sm-distance's do not)."""
    robot = get_robot(truth.robot)
    if session.method != "sm-distance-tilt":
        return math.nan
    ref = truth_in_session_frame(session, truth, state)
    xt = np.array([ref[n] for n in robot.param_names])
    res = session.outcome.result
    xc = np.array(res.x[:robot.n_params], dtype=float)
    box = planning.box_array(robot, planning.SM_BOX_7_5)   # the session's box
    if session.rounds is not None:           # centred on the reference pose as read
        box = box + session.rounds.box_centre(1.0)[:, None]
    try:
        plan = planning.sample_poses(robot, xt, box, count, np.random.default_rng(0),
                                     ik_options={"elbow": robot.elbow_of(session.reference_qm,
                                                                         xt)})
    except CalibrationError:          # the true arm reaches too little of that box
        return math.nan
    d = robot.fk(plan.qm, xc)[:, :3] - robot.fk(plan.qm, xt)[:, :3]
    return float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))


def normalized_errors(session, truth: SimTruth, state: dict) -> tuple[list[str], np.ndarray]:
    """Names and ``(calibrated - truth) / std`` of the identifiable parameters (a robot
    file's arm: :func:`station.simulation.serial_sessions.serial_errors`)."""
    if truth.spec is not None:
        return serial_errors(session, truth, state)
    res = session.outcome.result
    robot = get_robot(truth.robot)
    angles = set(getattr(robot, "angle_params", ()))
    ref = truth_in_session_frame(session, truth, state)
    names, z = [], []
    for j, (name, st) in enumerate(zip(res.names, res.status)):
        if not st.identifiable or name not in ref:
            continue
        d = res.x[j] - ref[name]
        if name in angles:
            d = (d + math.pi) % (2 * math.pi) - math.pi
        names.append(name)
        z.append(d / res.std[j])
    return names, np.array(z)


def excursion(session, truth: SimTruth) -> dict[str, float]:
    """Per coordinate, how far the true poses of the recorded poses lie outside the
    planned box (0 inside): sm-distance-tilt's box around the captured origin,
    sm-distance's around the base offset, the wrist's +-20 deg; {} for a robot file's
    arm (planned in joint space). The arm's scout (round 0) is not planned in the box:
    it steps a little from the reference in actuator space, and sm-distance's reference
    is a fixed qm that lies outside the box on some arms (0.33 m and 0.32 rad on seed
    9151), so its poses are left out."""
    if truth.spec is not None:
        return {}
    robot = get_robot(truth.robot)
    scout = ({p.index for p in session.plan_poses if p.round == 0}
             if session.rounds is not None else set())
    qm = [p["qm"] for i, p in session.measured.items() if i not in scout]
    if not qm:
        return {}
    xi = truth.xi()
    if session.method == "sm-distance-tilt":
        xi = reframe_nominal(robot, xi, session.reference_qm)
        box = planning.box_array(robot, planning.SM_BOX_7_5)
        if session.rounds is not None:           # centred on the reference pose as read
            box = box + session.rounds.box_centre(1.0)[:, None]
    elif robot.name == "agebot-sm":
        box = planning.box_array(robot, planning.SM_BOX_7_1,
                                 np.r_[robot.base_offset(xi), 0.0])
    else:
        box = planning.box_array(robot, planning.PM_BOX)
    if robot.name != "agebot-sm":
        return {}
    X = robot.fk(np.array(qm), xi)
    mid = box.mean(axis=1)
    X[:, 3] = mid[3] + (X[:, 3] - mid[3] + np.pi) % (2 * np.pi) - np.pi     # phi modulo 2 pi
    out = np.maximum(box[:, 0] - X, X - box[:, 1]).clip(min=0.0).max(axis=0)
    return dict(zip(robot.coords, out.tolist()))


def summary(scores: list[SessionScore]) -> dict:
    """Success rate, worst |error|/std, pooled RMS of error/std, coverage (share within
    2 std) and their standard errors, worst and RMS per parameter, largest excursion
    per coordinate. The errors of one session are correlated (one data set), so the
    standard errors take the sessions as the samples (the scatter of each session's
    mean z^2 and share within 2 std)."""
    done = [s for s in scores if s.completed]
    z = np.concatenate([s.z for s in done]) if done else np.zeros(0)
    per: dict[str, float] = {}
    sq: dict[str, list] = {}
    dofs: dict[str, list] = {}
    for s in done:
        for n, v in zip(s.names, s.z):
            per[n] = max(per.get(n, 0.0), abs(float(v)))
            sq.setdefault(n, []).append(float(v) ** 2)
            dofs.setdefault(n, []).append(s.dof)
    exc: dict[str, float] = {}
    for s in scores:
        for k, v in s.excursion.items():
            exc[k] = max(exc.get(k, 0.0), v)
    off = [s.offset for s in done if s.offset]
    rms = float(np.sqrt(np.mean(z ** 2))) if z.size else math.nan
    scored = [s for s in done if s.z.size]
    w = np.concatenate([s.whitened for s in scored]) if scored else np.zeros(0)
    rms_se = cov_se = math.nan
    if len(scored) > 1:
        k = math.sqrt(len(scored))
        rms_se = float(np.std([np.mean(s.z ** 2) for s in scored], ddof=1) / k / (2 * rms))
        cov_se = float(np.std([np.mean(np.abs(s.z) <= 2.0) for s in scored], ddof=1) / k)
    return {"sessions": len(scores), "completed": len(done),
            "offset_exact_se": [o["exact"] / o["se"] for o in off],
            "offset_reading_se": [o["reading"] / o["se"] for o in off],
            "offset_exact_um": [1e6 * o["exact"] for o in off],
            "success_rate": len(done) / max(len(scores), 1),
            "worst": float(np.max(np.abs(z))) if z.size else math.nan,
            "rms": rms, "rms_se": rms_se,
            "coverage_2std": float(np.mean(np.abs(z) <= 2.0)) if z.size else math.nan,
            "coverage_2std_se": cov_se,
            "n_errors": int(z.size), "worst_per_parameter": per,
            # the same errors whitened by each session's reported correlation
            "d2": [s.d2 for s in scored], "d2_k": [len(s.z) for s in scored],
            "d2_dof": [s.dof for s in scored],
            "d2_sum": float(sum(s.d2 for s in scored)),
            "rms_whitened": float(np.sqrt(np.mean(w ** 2))) if w.size else math.nan,
            "coverage_2std_whitened": float(np.mean(np.abs(w) <= 2.0)) if w.size else math.nan,
            "rms_per_parameter": {n: (math.sqrt(sum(v) / len(v)), len(v)) for n, v in sq.items()},
            # the sessions' fewest channel dof behind each parameter's errors (rms_bound)
            "dof_per_parameter": dofs,
            "excursion": exc,
            "tool_error": [s.tool_error for s in done],
            "heldout": {ch: [s.heldout.get(ch, math.nan) for s in done]
                        for ch in sorted({c for s in done for c in s.heldout})}}
