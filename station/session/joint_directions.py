"""Which way the joints turn, told by the draw-wire at the reference
(:func:`check_directions`; :mod:`station.session.plausibility` runs it after its test
move): a distance alone cannot tell which way one joint turned, two joints moved together
can. The readings at rest and the test moves' size are shared with the other checks."""
from __future__ import annotations

import numpy as np

from calibration.errors import ConfigError

MOVE_M = 0.03               # m of the tool a test move makes (nominal model)
SLACK_M = 2e-3              # m a reading may differ beyond the ratio's bounds


def read_at_rest(rig) -> dict:
    """Averaged readings without the std/drift limits: a mis-configured draw-wire
    reads wildly, and that is what the checks below are to say in words."""
    return rig.snapshot(std_limits={}, drift_limits={}).mean


def position_jacobian(robot, xi, q0) -> np.ndarray:
    """``(n, 3)``: row i the tool origin's velocity per unit of actuator i (FK steps)."""
    n = robot.n_actuators
    h = 1e-4
    p0 = robot.fk(np.atleast_2d(q0), xi)[0, :3]
    return np.array([(robot.fk(np.atleast_2d(q0 + h * np.eye(n)[i]), xi)[0, :3] - p0) / h
                     for i in range(n)])


def _direction_pairs(J) -> list[tuple[int, int]]:
    """Pairs ``(r, i)`` of actuators whose tool velocities are far from perpendicular
    (|cos| >= 0.3) and not small, each actuator once as ``i``: moving ``r`` with
    ``+i`` and with ``-i`` then gives two distances that differ by its direction."""
    speed = np.linalg.norm(J, axis=1)
    moving = [int(i) for i in np.argsort(-speed) if speed[i] > 0.05 * speed.max() > 0]
    cos = np.abs(J @ J.T) / np.maximum(np.outer(speed, speed), 1e-300)
    pairs: list[tuple[int, int]] = []
    known: list[int] = []
    while len(known) < len(moving):
        links = [(cos[r, i], r, i) for r in known for i in moving if i not in known]
        best = max(links, default=(0.0, -1, -1))
        if best[0] >= 0.3:            # the most telling pair from the joints linked so far
            pairs.append((best[1], best[2]))
            known.append(best[2])
        else:                         # none: the fastest joint left starts a new group
            known.append(next(i for i in moving if i not in known))
    return pairs


def direction_moves(robot, xi, q0) -> list[tuple[int, int, tuple, tuple]]:
    """The moves of :func:`check_directions` at ``q0`` (model ``xi``): ``(r, i, (dq+,
    dq-), (distance+, distance-))`` for each pair of :func:`_direction_pairs` whose two
    predicted distances differ enough to be told apart (each move reads the draw-wire
    once)."""
    q0 = np.asarray(q0, dtype=float)
    J = position_jacobian(robot, xi, q0)
    speed = np.linalg.norm(J, axis=1)
    p0 = robot.fk(np.atleast_2d(q0), xi)[0, :3]
    out = []
    for r, i in _direction_pairs(J):
        steps, want = [], []
        for sign in (1.0, -1.0):
            dq = np.zeros(robot.n_actuators)
            dq[r] = MOVE_M / 2 / speed[r]
            dq[i] = sign * MOVE_M / 2 / speed[i]
            steps.append(dq)
            want.append(float(np.linalg.norm(robot.fk(np.atleast_2d(q0 + dq), xi)[0, :3] - p0)))
        if abs(want[0] - want[1]) >= 2 * SLACK_M:
            out.append((r, i, tuple(steps), tuple(want)))
    return out


def check_directions(session, q0) -> str:
    """The draw-wire is zeroed at ``q0`` (the reference). A distance alone cannot tell
    which way one joint turned, but two joints moved together can: for each pair of
    :func:`_direction_pairs`, a move of ``+r +i`` and one of ``+r -i`` (about
    MOVE_M/2 of the tool each, nominal model) read two distances whose order is the
    sign of the two tool velocities' dot product, whatever the gear ratios' sizes. A
    joint that turns the other way than its start value says (a ratio ``k`` of the
    wrong sign, a drive's polarity) reverses the order: refused, naming it."""
    rig, cfg = session.rig, session.config
    checked, problems = [], []
    for r, i, steps, want in direction_moves(session.robot, session.nominal, q0):
        got = []
        for dq in steps:
            rig.move_to(q0 + dq)
            try:
                got.append(float(read_at_rest(rig)["distance"]))
            finally:
                rig.move_to(q0)
        checked.append(i)
        if (got[0] - got[1]) * (want[0] - want[1]) < 0 and abs(got[0] - got[1]) > SLACK_M:
            units = session.units
            problems.append(
                f"qm{r + 1} and qm{i + 1} do not turn as the start values say (one of them "
                f"the other way): moved together one way and the other, the draw-wire read "
                f"{units.text(got[0], 'm', '.3g')} and {units.text(got[1], 'm', '.3g')} where "
                f"the nominal model predicts {units.text(want[0], 'm', '.3g')} and "
                f"{units.text(want[1], 'm', '.3g')}: check the signs of k{r + 1} and "
                f"k{i + 1} in the start values (--nominal, the robot file) and the drives' "
                "polarity")
    if problems:
        more = (f"; {len(problems) - 1} more pairs disagree" if len(problems) > 1 else "")
        raise ConfigError(problems[0] + more + " (nothing was recorded)", source=cfg.source)
    return ("joints' directions as the model's (" + ", ".join(f"qm{i + 1}" for i in checked)
            + " against another joint)" if checked else "no joint direction testable here")
