"""Eq. 60's pose counts of the built-in robots' methods: the parameters a well-spread set
of poses identifies (N_R) and the rows a pose gives (p). The gate judges a fit's spread by
them; planning asks for that many poses (twice, by default)."""
from __future__ import annotations

from calibration.identifiability import minimum_poses
from calibration.methods import METHODS
from calibration.methods.sm_distance import zero_names

# N_R and p of each method (docs/models.md's method table) for the pose count of eq. 60; for
# sm-self-redundancy a "pose" of eq. 60 is a pair (its p = 2 rows dx, dy). The
# table's N_R counts the robot's parameters only: :func:`parameter_count` adds the
# draw-wire's zero offset where the method calibrates it.
NR_P = {"sm-distance": (9, 1), "sm-distance-tilt": (13, 2), "pm-ik": (8, 3), "pm-fk": (8, 3),
        "pm-tilt": (10, 2), "sm-self-redundancy": (7, 2), "sm-plane": (10, 1),
        "sm-full-pose": (13, 4), "sm-position": (13, 3)}
# a session's draw-wire zero is one reading (station.session.reference.ReferenceStep.capture_reference):
# the distance methods calibrate ``distance_off`` there
SESSION_ZERO = "reading"


def parameter_count(method: str, distance_zero: str = SESSION_ZERO) -> int:
    """N_R of eq. 60 for ``method`` on AGEBOT: the parameters a well-spread set of
    poses identifies, docs/models.md's (:data:`NR_P`) plus the method's draw-wire zero
    offset where the zero is a reading (:func:`calibration.methods.sm_distance.zero_names`)."""
    nr = NR_P[method][0]
    if "distance" in METHODS[method].channels:
        nr += len(zero_names(distance_zero))
    return nr


def minimum_count(method: str, components=None, distance_zero: str = SESSION_ZERO) -> int:
    """Eq. 60's minimum pose count of ``method`` (a session's by default; a trace
    passes its reference's ``zero``)."""
    p = NR_P[method][1]
    if method == "pm-fk" and components:
        p = len(components)
    return minimum_poses(parameter_count(method, distance_zero), p)
