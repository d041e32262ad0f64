"""Start values for a fit of a robot far from its nominal (the arm's distance methods):
the nominal told what the reference showed (:func:`told_start`), and start values grown
with the data (:func:`staged_start`). The final fit (:func:`station.fitting.batch.calibrate`)
and the arm's planning rounds (:mod:`station.planning.arm_rounds`) start here alike."""
from __future__ import annotations

import dataclasses

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import MethodData, build
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots.agebot_sm import wrap
from calibration.solver import SolverOptions, solve

#: the arm's distance methods: planned in rounds (station/planning/arm_rounds.py), and
#: their final fit also tried from start values grown with the data
ROUND_METHODS = ("sm-distance", "sm-distance-tilt")
#: what a refit on fewer poses than parameters learns, in this order
LEARN_FIRST = ("k1", "k2", "k3", "k4", "q4_off", "q3_off", "q2_off", "q1_off", "L4", "L3", "L2")


def fixed_for_rows(model) -> tuple[str, ...]:
    """With fewer rows than parameters, what the first poses can teach first: the
    gear ratios, then the joints' offsets; the rest stays at its start value. A robot
    file's ``fixed`` parameters are always held (freed by a partial fit, they moved the
    final fit of a UR5-like arm grown from it by up to 3.5 std)."""
    held = tuple(n for n in (getattr(model.robot, "fixed", ()) or ()) if n in model.names)
    free = len(model.row_channel) - 2
    if free >= len(model.names) - len(held):
        return held
    learn = LEARN_FIRST[:max(free, 0)]
    return tuple(n for n in model.names if n not in learn or n in held)


def staged_start(method: str, robot, data: MethodData, x, options: dict | None = None,
                 max_iter: int = 300, cuts=None):
    """Start values grown with the data: fits on the first quarter, half and three
    quarters of the poses in their recorded order (a session records from the
    reference outwards), or on the first ``cuts`` poses (e.g. where each of a
    session's rounds ended), each from the last, each of at most ``max_iter``
    iterations. For a robot so far from its start values that the fit of every pose
    at once does not converge. None if no stage gave finite values."""
    m = len(data.qm)
    x = np.array(x, dtype=float)
    got = False
    stages = [max(int(m * frac), 2) for frac in (0.25, 0.5, 0.75)] if cuts is None else \
        [int(k) for k in cuts if 2 <= int(k) < m]
    for k in stages:
        sub = dataclasses.replace(data, qm=data.qm[:k],
                                  channels={c: v[:k] for c, v in data.channels.items()})
        try:
            model = build(method, robot, sub, x, **(options or {}))
            res = solve(model, SolverOptions(max_iter=max_iter, fixed=fixed_for_rows(model)))
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            continue
        if np.all(np.isfinite(res.x)):
            x, got = np.array(res.x), True
    return x if got else None


def told_start(method: str, robot, nominal, reference_qm=None, tilt=None) -> np.ndarray:
    """The robot's start values told what the reference showed: the last link's offset
    turned so that the model's tilt there is the ``tilt`` read (the nominal offsets may
    be 0.3 rad off: every planned phi would be), and for sm-distance-tilt the base
    frame moved to the reference (eqs. 76-77). The nominal as it is without a
    reference. The session's rounds start here, and so does the final fit's grown
    start (:func:`station.fitting.batch.calibrate`): from the bare nominal, a drawn arm's fit
    of every pose, and the grown one, end in a local minimum 3 times in 10."""
    xi = np.array(nominal, dtype=float)
    if reference_qm is None:
        return xi
    ref = np.asarray(reference_qm, dtype=float)
    if tilt is not None:
        phi = robot.fk(np.atleast_2d(ref), xi)[0, 3]
        xi[robot.index("q4_off")] += float(wrap(tilt - phi))
    if method == "sm-distance-tilt":
        xi = reframe_nominal(robot, xi, ref)
    return xi
