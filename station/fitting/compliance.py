"""Beyond geometry: joint compliance under gravity, offered to a calibration and kept
only where the data support it (``app.py batch --compliance``; docs/compliance.md).

A URDF robot's compliant model bends joint i by ``c{i} * tau_i``: ``tau_i`` is
gravity's torque about the joint's axis at the pose, from the URDF's link inertials
and a payload the user states (:meth:`calibration.robots.urdf.UrdfRobot.loads`). The
identifiability analysis decides which compliances are calibrated (a joint whose axis
is vertical feels no torque: its column is zero).

:func:`compare` fits the trace twice, rigid and compliant, each through the
fit-quality gate, and says whether the data support the compliances:

* cross-validation over the fit poses (:mod:`calibration.cross_validation`): each fit
  pose's error as the fit without it predicts it, for both models, compared pose by
  pose with a signed-rank test; the compliant model is preferred where it predicts
  better with ``p < PREFER_P``;
* with held-out poses: per held-out pose, the squared 3D (or row) errors of the two
  models differ by ``d_p``; the held-out poses prefer the compliant model where
  ``mean(d) > SUPPORT_Z * std(d) / sqrt(poses)`` (the poses' differences taken as
  independent), the rigid one where ``mean(d) < -SUPPORT_Z * ...``;
* the compliances are supported where one of the two prefers them and the other does
  not prefer the rigid model;
* with neither (too few poses): a nested-model F test on the fit residuals (the
  compliant model's extra identified parameters against its residual variance),
  ``p < SUPPORT_P``.

The calibration written is the supported one; the other's figures go beside it in
the console, the report and the parameter file (``model_comparison``), so a term the
data do not support is never exported as if it were.
"""
from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np

from calibration import cross_validation as cv
from calibration import quality as q
from calibration.errors import CalibrationError

# the held-out improvement must exceed this many of its standard errors
SUPPORT_Z = 2.0
# without held-out poses, the F test's p-value must be below this
SUPPORT_P = 1e-3


def compliant_trace(trace, payload: dict | None = None):
    """``trace`` whose robot is its URDF robot with compliance (and ``payload``)."""
    src = trace.header.get("robot_file") or {}
    if "base_link" not in src:
        raise CalibrationError("--compliance needs a URDF robot (the links' inertials give the "
                               "gravity loads); this trace's robot is "
                               f"{trace.header.get('robot')}")
    src = dict(src, compliance=True)
    if payload:
        src["payload"] = dict(payload)
    header = dict(copy.deepcopy(trace.header), robot_file=src)
    return dataclasses.replace(trace, header=header, _model=None)


def _per_pose_sq(outcome) -> dict | None:
    """Held-out squared errors summed per pose: ``{pose index: sum of squares}`` (the
    validation poses' residuals at the outcome's solution), None without any."""
    from calibration.methods import build

    trace = outcome.trace
    if not trace.validation_poses:
        return None
    robot = trace.robot_model()
    data = trace.method_data(use="validation")
    model = build(trace.method, robot, data, outcome.result.x)
    r = model.evaluate(outcome.result.x)[0]
    rp = getattr(model, "row_pose", None)
    if rp is None:
        n = len(trace.validation_poses)
        rp = np.repeat(np.arange(n), len(r) // n)
    out: dict = {}
    for pos, v in zip(rp, r):
        idx = int(trace.validation_poses[int(pos)]["index"])
        out[idx] = out.get(idx, 0.0) + float(v) ** 2
    return out


def _fit_rss(outcome) -> float:
    r = outcome.result.residual
    return float(np.asarray(r) @ np.asarray(r))


def figures(o) -> dict:
    """A calibration's figures for the comparison: identifiable count, fit and held-out
    RMS (3D for points on the tool), the gate's verdict."""
    pts = [v for v in (o.validation or []) if v.get("points")]
    held = (pts[0]["points"]["rms_after"] if pts else
            (math.sqrt(np.mean([v["rms_after"] ** 2 for v in o.validation]))
             if o.validation else None))
    r = np.asarray(o.result.residual)
    if hasattr(o.model, "point_errors"):    # points on the tool: their 3D RMS
        r = o.model.point_errors(r)
    return {"identifiable": int(o.result.n_identifiable),
            "fit_rms": float(np.sqrt(np.mean(r ** 2))), "held_out_rms": held,
            "gate": "passed" if o.quality is None or o.quality.passed else "failed"}


def _unseen(outcome, sigma: dict) -> dict:
    """Each fit pose's error as the fit without it predicts it
    (:func:`calibration.cross_validation.unseen_errors`), keyed by the trace's pose
    index (the two models may have left different poses out as outliers); ``sigma``
    per channel weighs the rows, one for both models (each fit's own would measure
    each model's errors against its own residual level)."""
    from station.fitting.gate import row_poses

    model, res = outcome.model, outcome.result
    rp = row_poses(model)
    if rp is None:
        return {}
    r, W = model.evaluate(res.x)
    active = np.array([s.identifiable for s in res.status])
    w = q.row_weights(model.row_channel, model.channels, sigma)
    poses = outcome.trace.fit_poses
    return {int(poses[i]["index"]): v
            for i, v in cv.unseen_errors(r, W, w, active, rp).items()}


def _held_out(rigid, compliant) -> dict | None:
    """The held-out poses' verdict on the two models (module doc), None with fewer than
    3 held-out poses both predicted."""
    a, b = _per_pose_sq(rigid), _per_pose_sq(compliant)
    if not (a and b and set(a) == set(b) and len(a) >= 3):
        return None
    d = np.array([a[k] - b[k] for k in sorted(a)])
    mean, se = float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d)))
    z = mean / se if se > 0 else (math.inf if mean > 0 else 0.0)
    return {"z": float(z), "poses": len(d)}


def judge(rigid, compliant) -> dict:
    """Does the compliant outcome beat the rigid one beyond the uncertainty? A dict
    with both models' figures, ``supported`` and one ``statement`` for people."""
    out = {"rigid": figures(rigid), "compliant": figures(compliant)}
    names = [n for n, s in zip(compliant.result.names, compliant.result.status)
             if s.identifiable and n.startswith("c") and n[1:].isdigit()]
    out["compliances"] = names
    if not names:
        out.update(supported=False, test="none", statement=(
            "compliance offered: no joint's compliance is identifiable from these poses "
            "(each joint's gravity torque barely changes, or its axis is vertical)"))
        return out
    sigma = dict(rigid.result.sigma)
    c = cv.compare_models(_unseen(rigid, sigma), _unseen(compliant, sigma))
    held = _held_out(rigid, compliant)
    if c is not None or held is not None:
        cv_ok, cv_bad = c is not None and c.better, c is not None and c.worse
        held_ok = held is not None and held["z"] > SUPPORT_Z
        held_bad = held is not None and held["z"] < -SUPPORT_Z
        ok = (cv_ok and not held_bad) or (held_ok and not cv_bad)
        parts = []
        if c is not None:
            per = math.sqrt(3.0) if hasattr(compliant.model, "point_errors") else 1.0
            out["cross_validation"] = {"poses": c.poses, "wins": c.wins, "p": c.p,
                                       "p_worse": c.p_worse, "rms_rigid": c.rms_a * per,
                                       "rms_compliant": c.rms_b * per}
            parts.append(
                f"cross-validation over {c.poses} fit poses (each predicted by the fit "
                f"without it): {_mm(c.rms_a * per)} -> {_mm(c.rms_b * per)}"
                f"{' per point' if per != 1.0 else ' RMS'}, smaller for {c.wins} of "
                f"{c.poses} poses, signed-rank p = {c.p:.2g} "
                f"({'below' if c.better else 'not below'} {cv.PREFER_P:g})")
        if held is not None:
            ra, rb = out["rigid"]["held_out_rms"], out["compliant"]["held_out_rms"]
            out["z"] = held["z"]
            parts.append(f"the held-out poses: their error {_mm(ra)} -> {_mm(rb)}, "
                         f"{held['z']:.2g} times its standard error over {held['poses']} "
                         f"poses ({'more' if held_ok else 'not more'} than {SUPPORT_Z:g})")
        out.update(test="cross-validation" if c is not None else "held-out",
                   supported=bool(ok), statement=(
                       f"compliance {'supported' if ok else 'not supported'} "
                       f"(the compliances of {', '.join(names)}) by " + "; by ".join(parts)))
        return out
    rss_a, rss_b = _fit_rss(rigid), _fit_rss(compliant)
    extra = compliant.result.n_identifiable - rigid.result.n_identifiable
    dof = len(compliant.result.residual) - compliant.result.n_identifiable
    if extra <= 0 or dof <= 0 or rss_b <= 0:
        out.update(supported=False, test="F", statement="compliance not supported: it adds "
                   "no identifiable parameter to the fit")
        return out
    from scipy.special import fdtrc

    F = ((rss_a - rss_b) / extra) / (rss_b / dof)
    p = float(fdtrc(extra, dof, max(F, 0.0)))
    ok = p < SUPPORT_P
    out.update(test="F", F=float(F), p=p, supported=bool(ok), statement=(
        f"compliance {'supported' if ok else 'not supported'} by the fit (no held-out poses): "
        f"residual RMS {_mm(out['rigid']['fit_rms'])} -> {_mm(out['compliant']['fit_rms'])}, "
        f"F = {F:.3g} on {extra} and {dof} degrees of freedom, p = {p:.2g} "
        f"({'below' if ok else 'not below'} {SUPPORT_P:g}); hold some poses out to judge it "
        f"on poses the fit has not seen"))
    return out


def _mm(v) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.4g} mm"


def _gate_failures(e) -> str:
    """What the compliant fit's gate refused, without the command's own advice ("no
    parameter file written": the rigid fit's file is written)."""
    quality = getattr(getattr(e, "outcome", None), "quality", None)
    return quality.summary() if quality is not None else str(e)


def compare(trace, calibrate, payload: dict | None = None):
    """Fit ``trace`` rigid and compliant with ``calibrate(trace) -> BatchOutcome`` and
    judge them (:func:`judge`). A compliant fit the gate refuses is not supported; a
    rigid fit the gate refuses is compared all the same (a bent arm's rigid model does
    not predict), and its refusal stands unless the compliant fit passes and is
    supported. Returns ``(chosen outcome, comparison dict)``."""
    from station.fitting.verdict import FitQualityError

    offered = compliant_trace(trace, payload)     # a robot without inertials: an error
    try:
        rigid, rigid_error = calibrate(trace), None
    except FitQualityError as e:      # a bent arm's rigid fit may fail: try the compliant
        if e.outcome is None:
            raise
        rigid, rigid_error = e.outcome, e
    try:
        comp = calibrate(offered)
    except FitQualityError as e:
        if rigid_error is not None:
            raise rigid_error from None
        info = {"supported": False, "test": "gate",
                "statement": "compliance not supported: the compliant fit failed the "
                             f"fit-quality gate ({_gate_failures(e)}); the rigid fit is kept"}
        info["rigid"] = figures(rigid)
        if e.outcome is not None:
            info["compliant"] = figures(e.outcome)
        return rigid, info
    except CalibrationError:
        if rigid_error is not None:
            raise rigid_error from None
        raise
    info = judge(rigid, comp)
    if rigid_error is not None and not info["supported"]:
        raise rigid_error
    return (comp if info["supported"] else rigid), info
