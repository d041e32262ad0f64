"""What a session is asked to plan: the methods a station session measures (unattended,
or by guided touching), the plan request (pose counts, held-out poses, seed, design,
rounds) and what the operator is told at a touched pose."""
from __future__ import annotations

from dataclasses import dataclass, field

from calibration.errors import CalibrationError
from calibration.methods import METHODS

# methods a session measures unattended (the wizard offers these) and those that
# need guided touching (a session with a ``touch`` callback)
SESSION_METHODS = ("sm-distance", "sm-distance-tilt", "pm-ik", "pm-fk", "pm-tilt", "sm-markers")
TOUCH_METHODS = ("sm-self-redundancy", "sm-plane")
# not identifiable, influencing the model: the session's start values must be right
MUST_KNOW = {"sm-plane": ("L4", "theta0", "a0", "plane_a", "plane_b", "plane_c"),
             "sm-self-redundancy": ("L4",)}
PLANE = ("plane_a", "plane_b", "plane_c")


@dataclass
class PlanRequest:
    """How many poses (None: eq. 60 times ``margin``) and held-out poses, and the seed.

    design: ``"optimal"`` (each round's fit poses the D-optimal choice from a pool the
    planner draws, given the poses already measured; :mod:`station.planning.pose_design`) or
    ``"random"``. target: None or ``(name, std)``: poses are added until the predicted
    std of parameter ``name`` (``"heldout"``: the tool's held-out error) meets it."""

    count: int | None = None
    validation: int | None = None
    seed: int = 0
    margin: float = 2.0
    components: tuple[str, ...] = ("alpha", "beta", "gamma")
    # the arm's distance methods in rounds, live-watched (station/planning/arm_rounds.py): what
    # app.py run (unless --one-shot) and the wizard ask for
    grow: bool = False
    notes: list[str] = field(default_factory=list)
    design: str = "optimal"
    target: tuple[str, float] | None = None


def check_method(method: str) -> None:
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r} (known: {', '.join(METHODS)})")
    if method not in SESSION_METHODS + TOUCH_METHODS:
        raise CalibrationError(
            f"method {method} needs a pose tracker, which this station does not have; record "
            f"its trace elsewhere and calibrate it with app.py batch. Station sessions "
            f"support: {', '.join(SESSION_METHODS + TOUCH_METHODS)}")


def touch_instructions(method: str) -> str:
    """What the operator does at each pose of a guided-touching method."""
    if method == "sm-plane":
        return ("The arm stops about 2 cm from the plane. Jog the tool tip towards the plane "
                "until it just touches it (feeler gauge), then confirm: the actuator values are "
                "recorded. Touch at every planned point, spread over the plane.")
    if method == "sm-self-redundancy":
        return ("Poses come in pairs. At the first pose of a pair touch the mark (the pin) with "
                "the tool tip and confirm; at the second the last link is turned the other way: "
                "bring the tip onto the same mark again and confirm. Only x and y must match.")
    return ""
