"""Shared pieces of the PM methods (report section 10): data checks, the
orientation components, forward kinematics that keeps each pose's assembly
mode, and the operator's note on the compensated parameters (eqs. 112-113).
"""
from __future__ import annotations

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods.base import RobotMethod, channel

COMPONENTS = ("alpha", "beta", "gamma")
STARTS = ("robust", "nominal")
# a pose whose FK solution moves more than this (rad) from its previous solution
# in one evaluation is suspected of having changed assembly mode
MODE_JUMP = 0.5
# FK closure tolerance (m): near round-off, so that noise-free fits end smoothly
FK_TOL = 1e-14

COMPENSATION_NOTE = (
    "q3_off and k3 (offset and gear ratio of actuator 3) cannot be identified from "
    "orientation measurements: scaling every length together with the gear ratios, or "
    "shifting the platform height v together with all three offsets, moves no actuator. "
    "They were kept at their nominal values and the other parameters absorbed the "
    "difference (report eqs. 112-113). The calibrated a1, a2, l, v, offsets and gear "
    "ratios may therefore differ from the real robot's, but the calibrated model returns "
    "the correct actuator values for every orientation: it is fit to drive the robot. "
    "Do not compare these values with drawings or with a calibration made from other "
    "nominal q3_off, k3.")


def compensation_note(q3_off: float | None = None, k3: float | None = None) -> str:
    """Plain-words note for the operator about q3_off, k3 (eqs. 112-113);
    with values, it names the nominal values the result refers to."""
    if q3_off is None or k3 is None:
        return COMPENSATION_NOTE
    return (COMPENSATION_NOTE + f" This calibration refers to q3_off = {q3_off:.6g}, "
            f"k3 = {k3:.6g} (1/{1.0 / k3:.6g}).")


def parse_components(components) -> tuple[str, ...]:
    """Validated measured orientation components, in the order alpha, beta, gamma."""
    if components is None:
        return COMPONENTS
    if isinstance(components, str):
        components = (components,)
    comps = tuple(components)
    bad = [c for c in comps if c not in COMPONENTS]
    if bad or not comps or len(set(comps)) != len(comps):
        raise CalibrationError(f"components must be a non-empty subset of {list(COMPONENTS)} "
                               f"without repeats, not {list(comps)}")
    if list(comps) != [c for c in COMPONENTS if c in comps]:
        raise CalibrationError(f"components must be in the order alpha, beta, gamma, not {list(comps)}")
    return comps


def orientation_channel(measured: dict, comps, method: str) -> np.ndarray:
    """Measured components ``(m, len(comps))`` from the ``orientation`` channel, which
    holds either all three angles or just the measured subset (file-formats.md)."""
    a = channel(measured, "orientation", method)
    if a.ndim == 1:
        a = a[:, None]
    idx = [COMPONENTS.index(c) for c in comps]
    if a.shape[1] == 3 and len(comps) < 3:
        return a[:, idx].copy()
    if a.shape[1] != len(comps):
        raise CalibrationError(f"channel 'orientation' has {a.shape[1]} values per pose; the "
                               f"measured components are {list(comps)}")
    return a


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


class PMMethod(RobotMethod):
    """A method over the PM model (``xi = a1, a2, l, v, q_off, k``)."""

    robot_kind = "parallel-wrist"
    default_damping = 1e-4
    evaluates_everywhere = False  # the PM cannot assemble everywhere
    notes = (COMPENSATION_NOTE,)

    def operator_notes(self, x=None) -> tuple[str, ...]:
        """:attr:`notes` with the q3_off, k3 values the result refers to."""
        x = self.x0 if x is None else x
        i = self.robot.index("q3_off")
        return (compensation_note(float(x[i]), float(x[self.robot.index("k3")])),)


class ModeKeepingFK:
    """FK of fixed actuator values over changing parameters, one assembly mode per pose.

    Each evaluation starts every pose from its previous solution; a pose whose
    solution jumps by more than :data:`MODE_JUMP` is recomputed from its reference
    orientation (the start guess) and, if it still jumps, the evaluation fails
    (the solver then rejects that step)."""

    def __init__(self, robot, qm, guess):
        self.robot, self.qm = robot, qm
        self.reference = np.array(guess, dtype=float)
        self.last = self.reference.copy()

    def __call__(self, x) -> np.ndarray:
        X = self.robot.fk(self.qm, x, guess=self.last, tol=FK_TOL)
        jump = np.max(np.abs(X - self.last), axis=1) > MODE_JUMP
        if np.any(jump):
            Xr = self.robot.fk(self.qm[jump], x, guess=self.reference[jump], tol=FK_TOL)
            if np.any(np.max(np.abs(Xr - self.reference[jump]), axis=1) > 2 * MODE_JUMP):
                raise CalibrationError("the PM model changed assembly mode at "
                                       f"{int(jump.sum())} pose(s)")
            X[jump] = Xr
        self.last = X
        return X
