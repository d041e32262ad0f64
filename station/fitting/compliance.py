"""Beyond geometry: joint compliance under gravity, offered to a calibration and kept
only where the data support it (``app.py batch --compliance``; docs/compliance.md).

A URDF robot's compliant model bends joint i by ``c{i} * tau_i``: ``tau_i`` is
gravity's torque about the joint's axis at the pose, from the URDF's link inertials
and a payload the user states (:meth:`calibration.robots.urdf.UrdfRobot.loads`). The
identifiability analysis decides which compliances are calibrated (a joint whose axis
is vertical feels no torque: its column is zero).

:func:`compare` fits the trace twice, rigid and compliant, each through the
fit-quality gate, and says whether the data support the compliances:

* with held-out poses: the compliant model must predict them better, by more than the
  uncertainty of the difference. Per held-out pose, the squared 3D (or row) errors of
  the two models differ by ``d_p``; the improvement is supported where ``mean(d) >
  SUPPORT_Z * std(d) / sqrt(poses)`` (the poses' differences taken as independent);
* without: a nested-model F test on the fit residuals (the compliant model's extra
  identified parameters against its residual variance), ``p < SUPPORT_P``.

The calibration written is the supported one; the other's figures go beside it in
the console, the report and the parameter file (``model_comparison``), so a term the
data do not support is never exported as if it were.
"""
from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np

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


def judge(rigid, compliant) -> dict:
    """Does the compliant outcome beat the rigid one beyond the uncertainty? A dict
    with both models' figures, ``supported`` and one ``statement`` for people."""
    out = {"rigid": figures(rigid), "compliant": figures(compliant)}
    names = [n for n, s in zip(compliant.result.names, compliant.result.status)
             if s.identifiable and n.startswith("c") and n[1:].isdigit()]
    out["compliances"] = names
    a, b = _per_pose_sq(rigid), _per_pose_sq(compliant)
    if not names:
        out.update(supported=False, test="none", statement=(
            "compliance offered: no joint's compliance is identifiable from these poses "
            "(each joint's gravity torque barely changes, or its axis is vertical)"))
        return out
    if a and b and set(a) == set(b) and len(a) >= 3:
        d = np.array([a[k] - b[k] for k in sorted(a)])
        mean, se = float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d)))
        z = mean / se if se > 0 else (math.inf if mean > 0 else 0.0)
        ok = z > SUPPORT_Z
        ra, rb = out["rigid"]["held_out_rms"], out["compliant"]["held_out_rms"]
        out.update(test="held-out", z=float(z), supported=bool(ok), statement=(
            f"compliance {'supported' if ok else 'not supported'} by the held-out poses: "
            f"their error {_mm(ra)} -> {_mm(rb)} with the compliances of "
            f"{', '.join(names)}, an improvement of {z:.2g} times its standard error over "
            f"{len(d)} poses ({'more' if ok else 'not more'} than {SUPPORT_Z:g})"))
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
