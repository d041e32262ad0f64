"""The fit-quality gate's judgments of a fit (:mod:`station.fitting.gate`): its poses'
spread (eq. 60), whether its values are plausible for the robot (AGEBOT's gear ratios and
lengths; a robot file's or URDF robot's corrections against its description), whether the
model explains the readings, and the held-out validation. Each adds checks to the gate's
:class:`~station.fitting.verdict.Quality`."""
from __future__ import annotations

import math

import numpy as np

from calibration import identifiability as ident
from calibration import quality as q
from station.fitting.pose_count import NR_P, parameter_count
from station.fitting.verdict import Quality
from station.recording.trace import pose_name
from station.outputs.params_file import PLAUSIBLE_FACTOR, factor_judged
from station.outputs.units import MM_DEG, channel_si

# The calibrated fit may predict the held-out poses at most this much worse than
# the start values before the gate calls it worse (noise on an already good start).
VALIDATION_TOLERANCE = 1.1


def check_validation(quality, validation: list[dict]) -> None:
    """The held-out validation (:func:`station.fitting.validation.validation_errors`)
    judged: per channel not worse than the start values (:data:`VALIDATION_TOLERANCE`; points
    on the tool by their 3D errors), poses outside the fitted ranges reported, a held-out
    reading beyond its prediction's std failed."""
    by_points = any(v.get("points") for v in validation)
    for v in validation:
        before, after = v.get("rms_before"), v.get("rms_after")
        pts = v.get("points")
        if by_points and not pts:
            continue              # points on the tool: judged once, by their 3D errors
        if pts:
            before, after = pts.get("rms_before"), pts.get("rms_after")
        if before is None or after is None or not math.isfinite(after):
            continue
        ok = after <= VALIDATION_TOLERANCE * before
        if pts:
            w = pts["worst"][0]
            verb = "went" if ok else "is worse than the start:"
            text = (f"validation: held-out points' 3D RMS {verb} "
                    f"{mm(pts.get('rms_before'))} -> {mm(pts['rms_after'])} mm "
                    f"(max {mm(pts['max_after'])} mm at {pose_name(w)} point {w['point']}; "
                    f"{pts['n']} points of {pts['poses']} poses)")
        else:
            text = (f"validation: {v['channel']} RMS on {v['n']} held-out rows "
                    f"{'went' if ok else 'is worse than the start:'} "
                    f"{people(before, v['channel'], v['unit'])} -> "
                    f"{people(after, v['channel'], v['unit'])}")
        extra = {"points": dict(pts)} if pts else {}
        quality.check("validation", ok, text, channel=v["channel"], rms_before=before,
                      rms_after=after, **extra)
    beyond = [v for v in validation if v.get("outside_range")]
    if beyond:             # the same poses for every channel: one line, each channel's errors
        out = beyond[0]["outside_range"]
        named = ", ".join(f"{pose_name(p)}: {p['why']}" if p.get("where") else
                          f"pose {p['pose']} ({p['why']})" for p in out["poses"][:3])
        more = f" and {len(out['poses']) - 3} more" if len(out["poses"]) > 3 else ""
        figs = []
        for v in beyond:
            o = v["outside_range"]
            if v.get("points"):
                figs.append(f"points RMS {mm(o['rms'])}, max {mm(o['max'])} mm")
            else:
                figs.append(f"{v['channel']} RMS {people(o['rms'], v['channel'], v['unit'])}, "
                            f"max {people(o['max'], v['channel'], v['unit'])}")
        quality.check("extrapolation", True,
                      f"validation: {len(out['poses'])} held-out pose(s) lie outside "
                      f"the fitted poses' joint ranges: {named}{more}; their errors "
                      f"({'; '.join(figs)}) are an extrapolation, reported and not judged",
                      channel=beyond[0]["channel"], outside_range=out)
    # sm-markers where the residuals are the model's error: the level the fit's poses show
    level = next((c["level"] for c in quality.checks if c.get("level")), None)
    for v in validation:
        o = v.get("outlier")
        if o:
            where = pose_name(o) if o.get("pose") is not None else "a held-out pose"
            if "point" in o:
                what = (f"validation: held-out {where} point {o['point']} is "
                        f"{mm(o['residual'])} mm off the calibration's prediction, "
                        f"{o['t']:.3g} times its predicted std (threshold "
                        f"{o['threshold']:.3g} over {o['rows_tested']} held-out points)")
                size = o["t"] * level["sigma"] if level else math.inf   # studentized, m
                if size <= level_limit(level):
                    quality.check("validation", True, f"{what}, within the model-error level "
                                  f"the fit's poses show ({mm(size)} mm studentized, an "
                                  f"outlier beyond {mm(level_limit(level))} mm)",
                                  channel=v["channel"], heldout=dict(o), short=True)
                    continue
            else:
                what = (f"validation: held-out {where} {v['channel']} is "
                        f"{o['residual']:.4g} {v['unit']} off the calibration's "
                        f"prediction, {o['t']:.3g} times its predicted std {o['std']:.3g} "
                        f"{v['unit']} (threshold {o['threshold']:.3g} over "
                        f"{o['rows_tested']} held-out rows)")
            quality.check("validation", False, what + ": a bad reading or a model that "
                          "does not predict; check that pose's reading",
                          channel=v["channel"], heldout=dict(o))


def level_limit(level) -> float:
    """A point's studentized 3D size beyond which it stands out of the model-error level
    (:mod:`station.fitting.pose_outliers`; its limit is per row of x, y, z)."""
    return level["limit"] * math.sqrt(3.0) if level else -math.inf


def people(v, channel: str, si: str | None = None) -> str:
    """A channel's figure for people: mm and degrees with the unit (station.outputs.units)."""
    return MM_DEG.text(v, si if si is not None else channel_si(channel), ".4g")


def mm(v) -> str:
    """A length in metres as millimetres for people (``-`` where unknown)."""
    return "-" if v is None or not math.isfinite(v) else f"{v * 1e3:.3g}"


def check_poses(quality, trace, model, result) -> None:
    qm = getattr(model, "qm", None)
    if qm is None:
        return
    distinct = q.distinct_poses(qm)
    n_id = result.n_identifiable
    need = ident.minimum_poses(n_id, model.p)
    expected = (parameter_count(trace.method, trace.distance_zero) if trace.method in NR_P
                else n_id)
    if "robot_file" in trace.header:
        expected = n_id    # NR_P counts AGEBOT's parameters
    if trace.method == "pm-fk" and trace.header.get("components"):
        expected = n_id    # fewer components may identify fewer parameters
    ok = distinct >= min(need, model.n_poses) and n_id >= expected
    why = ""
    if n_id < expected:
        why = (f"; only {n_id} of {len(result.names)} parameters are identifiable where a "
               f"well-spread set of poses identifies {expected}")
    quality.check("poses", ok, f"poses: {distinct} distinct of {model.n_poses} fitted "
                  f"(eq. 60 recommends >= {need} for {n_id} identifiable){why}",
                  distinct=distinct, poses=int(model.n_poses), identifiable=int(n_id),
                  expected_identifiable=int(expected), short=bool(ok and distinct < need))




def check_plausibility(quality, model, result, method, serial: bool) -> None:
    """The gate's plausibility check of ``result`` against the start values
    ``model.x0``: AGEBOT's parameters (:func:`check_plausible`), a robot file's or
    URDF robot's (``serial``, :func:`check_plausible_serial`)."""
    if serial:
        check_plausible_serial(quality, model, result)
    else:
        check_plausible(quality, model, result, method)


def implausible(model, result, method, serial: bool) -> list[dict]:
    """The parameters :func:`check_plausibility` refuses (name, start, calibrated)."""
    quality = Quality()
    check_plausibility(quality, model, result, method, serial)
    return [] if quality.passed else quality.checks[-1]["parameters"]


def check_plausible(quality, model, result, method) -> None:
    """The robot's gear ratios (``k*``) and lengths keep their sign and stay within
    :data:`PLAUSIBLE_FACTOR` of the start; offsets, a method's extra parameters
    (plane, inclinometer mount) and sm-distance-tilt's frame (``a0``) are free."""
    robot = getattr(model, "robot", None)
    bad = []
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        x0, x = float(model.x0[j]), float(result.x[j])
        if (not st.identifiable or robot is None or not math.isfinite(x)
                or not factor_judged(name, x0, robot, serial=False, method=method)):
            continue
        ratio = x / x0
        if not 1 / PLAUSIBLE_FACTOR <= ratio <= PLAUSIBLE_FACTOR:
            bad.append((name, x0, x, ratio))
    if bad:
        quality.check("plausible", False, "plausible: " + ", ".join(
            f"{n} went from {a:.4g} to {b:.4g} ({r:.3g} times)" for n, a, b, r in bad)
            + f"; gear ratios and lengths move by less than a factor {PLAUSIBLE_FACTOR:g} on a "
            "real robot: a reading's sign, unit or word order is likely wrong",
            parameters=[{"name": n, "start": a, "calibrated": b} for n, a, b, _ in bad])
    else:
        quality.check("plausible", True, "plausible: gear ratios and lengths within a factor "
                      f"{PLAUSIBLE_FACTOR:g} of the start")


# A robot file's or URDF robot's calibration, against its start values: a joint's
# correction beyond these is a wrong unit, sign, zero or robot file, not a robot.
SERIAL_SHIFT = 0.05     # share of the robot's length a URDF joint origin may move
SERIAL_TURN = 0.1       # rad a URDF joint origin or the instrument frame may turn
SERIAL_ANGLE = 0.35     # rad a robot file's alpha, beta, theta may move
SERIAL_ZERO = 0.5       # rad (m: SERIAL_SHIFT) a URDF joint's zero may move
# The calibrated model must explain the readings: the residual RMS of a length
# channel at most this share of the robot's size, of an angle channel this many rad.
EXPLAIN_LENGTH = 0.05
EXPLAIN_ANGLE = 0.02
LENGTH_CHANNELS = ("x", "y", "z", "marker", "distance")
ANGLE_CHANNELS = ("roll", "pitch", "yaw", "phi")


def robot_size(model) -> float:
    """How far the tool moves over the fit's poses at the start values (RMS distance
    of its origin from their mean, at least 0.1 m): the scale a calibration's lengths
    and residuals are judged against."""
    robot = model.robot
    try:
        T = robot.frames(model.qm, np.asarray(model.x0, dtype=float)[:robot.n_params])
    except Exception:  # noqa: BLE001 - a model without frames has no size to judge by
        return 1.0
    p = T[:, :3, 3]
    return max(float(np.sqrt(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1)))), 0.1)


def robot_reach(model) -> float:
    """The robot's own length at its start values: the sum of its chain's translations
    (joint origins, links, the tool), the instrument frame left out (at least 0.1 m)."""
    robot = model.robot
    chain = getattr(robot, "chain", None)
    if chain is None:
        return 1.0
    xi = np.asarray(model.x0, dtype=float)[:robot.n_params]
    names = robot.param_names
    total = 0.0
    for f in chain.factors:
        if f.kind[0] != "t" or f.joint is not None:
            continue
        if any(names[i].startswith("base_") for i, _c in f.terms):
            continue
        total += abs(f.const + sum(c * xi[i] for i, c in f.terms))
    return max(total, 0.1)


def check_plausible_serial(quality, model, result) -> None:
    """A robot file's or URDF robot's calibration within what a real robot departs from
    its description: ratios within a factor :data:`PLAUSIBLE_FACTOR` and of the same
    sign, a robot file's lengths too (or, from 0, within :data:`SERIAL_SHIFT` of the
    robot's length, :func:`robot_reach`), its angles within :data:`SERIAL_ANGLE`; a URDF
    robot's joint origins within :data:`SERIAL_SHIFT` of its length and
    :data:`SERIAL_TURN`, its zeros within
    :data:`SERIAL_ZERO`, the instrument frame's correction within :data:`SERIAL_TURN`."""
    robot = model.robot
    size = robot_reach(model)
    urdf = hasattr(robot, "calibrated_origins")
    bad = []
    for j, (name, st) in enumerate(zip(result.names, result.status)):
        if not st.identifiable or name not in robot.param_names:
            continue
        x0, x = float(model.x0[j]), float(result.x[j])
        if not math.isfinite(x):
            bad.append((name, x0, x, "is not finite"))
            continue
        d = x - x0
        ratio_ok = (not factor_judged(name, x0, robot, serial=True)
                    or 1 / PLAUSIBLE_FACTOR <= x / x0 <= PLAUSIBLE_FACTOR)
        if name.startswith("k"):
            if not ratio_ok:
                bad.append((name, x0, x, f"{x / x0:.3g} times the start"))
        elif urdf and name.startswith("j") and name.endswith(("_x", "_y", "_z")):
            if abs(d) > SERIAL_SHIFT * size:
                bad.append((name, x0, x, f"{d * 1e3:.4g} mm, beyond {SERIAL_SHIFT:.0%} of the "
                                         f"robot's length {size:.3g} m"))
        elif urdf and (name.startswith("j") or name.startswith("base_r")):
            if abs(d) > SERIAL_TURN:
                bad.append((name, x0, x, f"turned {math.degrees(d):.3g} deg"))
        elif name.endswith("_off"):
            i = int(name[1:-4])
            kind = robot.spec.joints[i - 1].kind
            # a robot file's prismatic zero is wherever its rail's encoder counts from
            lim = (SERIAL_ZERO if kind == "R" else SERIAL_SHIFT * size if urdf else math.inf)
            if abs(d) > lim:
                bad.append((name, x0, x, "a zero far from the URDF's (a joint map's offset or "
                                         "sign?)" if urdf else "a zero far from the robot "
                                         "file's (a joint column's offset or sign?)"))
        elif not urdf and name[0] in "da" and name[1:].isdigit():
            if not ratio_ok or (abs(x0) <= 1e-3 and abs(d) > SERIAL_SHIFT * size):
                bad.append((name, x0, x, f"{d * 1e3:.4g} mm from the robot file's"))
        elif not urdf and name.startswith(("alpha", "beta", "theta")):
            if abs(d) > SERIAL_ANGLE:
                bad.append((name, x0, x, f"turned {math.degrees(d):.3g} deg"))
    if bad:
        quality.check("plausible", False, "plausible: " + ", ".join(
            f"{n} went from {a:.4g} to {b:.4g} ({why})" for n, a, b, why in bad)
            + "; a real robot departs from its description by less: a reading's unit, sign or "
            "frame, the joint values' units, zeros or order, or the robot file or URDF itself "
            "is likely wrong", parameters=[{"name": n, "start": a, "calibrated": b}
                                        for n, a, b, _ in bad])
    else:
        quality.check("plausible", True, "plausible: every correction within what a real "
                      "robot departs from its description")


def check_explains(quality, model, result) -> None:
    """The calibrated model explains the readings: a length channel's residual RMS at
    most :data:`EXPLAIN_LENGTH` of the robot's size, an angle channel's at most
    :data:`EXPLAIN_ANGLE` rad. Without a stated noise the rest of the gate cannot tell
    a model that fits from one that does not (a unit, a mirrored axis, a wrong joint)."""
    size = robot_size(model)
    bad = []
    for ch, rms in (result.residual_rms or {}).items():
        if not math.isfinite(rms):
            bad.append(f"{ch} not finite")
        elif ch in LENGTH_CHANNELS and rms > EXPLAIN_LENGTH * size:
            bad.append(f"{ch} {rms * 1e3:.4g} mm ({rms / size:.0%} of the robot's size "
                       f"{size:.3g} m)")
        elif ch in ANGLE_CHANNELS and rms > EXPLAIN_ANGLE:
            bad.append(f"{ch} {math.degrees(rms):.3g} deg")
    if bad:
        quality.check("explains", False, "explains: the calibrated model leaves residual RMS "
                      + ", ".join(bad) + ": it does not explain the readings (a unit, e.g. "
                      "degrees read as radians or mm as m, a mirrored or swapped axis, a wrong "
                      "joint column or robot file)")
