"""The calibration methods, by the names used in traces and parameter files.

Each method is a measurement model (:class:`calibration.model.MeasurementModel`);
:func:`build` makes one from the arrays of a data set. A new method is a
small module plus one line in ``METHODS``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from importlib import import_module

import numpy as np

from calibration.errors import CalibrationError


@dataclass(frozen=True)
class MethodData:
    """A data set for a method, as arrays (what a trace holds).

    qm:           ``(m, n)`` actuator values of the poses.
    channels:     measured channel -> ``(m,)`` or ``(m, k)`` array.
    group:        ``(m,)`` group of each pose (sm-self-redundancy), or None.
    reference_qm: actuator values of the reference record, or None.
    components:   measured orientation components (pm-fk), e.g. ("alpha", "beta").
    distance_zero: the draw-wire's zero at the reference: ``"exact"`` (the report's
                  model) or ``"reading"`` (one noisy reading: the distance methods
                  calibrate ``distance_off``).
    """

    qm: np.ndarray
    channels: dict = field(default_factory=dict)
    group: np.ndarray | None = None
    reference_qm: np.ndarray | None = None
    components: tuple[str, ...] | None = None
    distance_zero: str = "exact"


@dataclass(frozen=True)
class MethodInfo:
    name: str
    robot: str
    module: str
    cls: str
    channels: tuple[str, ...]  # trace channels the method reads
    reference: str | None = None  # role of the reference record it needs
    extra_params: tuple[str, ...] = ()
    section: str = ""


METHODS: dict[str, MethodInfo] = {m.name: m for m in (
    MethodInfo("sm-full-pose", "agebot-sm", "sm_full_pose", "FullPose", ("pose",), section="7.1"),
    MethodInfo("sm-distance", "agebot-sm", "sm_distance", "Distance", ("distance",),
               reference="reference-point", section="7.2"),
    MethodInfo("sm-self-redundancy", "agebot-sm", "sm_self_redundancy", "SelfRedundancy", (),
               section="7.3"),
    MethodInfo("sm-plane", "agebot-sm", "sm_plane", "Plane", (),
               extra_params=("plane_a", "plane_b", "plane_c"), section="7.4"),
    MethodInfo("sm-distance-tilt", "agebot-sm", "sm_distance_tilt", "DistanceTilt",
               ("distance", "tilt"), reference="base-origin", section="7.5"),
    MethodInfo("pm-ik", "agebot-pm", "pm_ik", "InverseKinematics", ("orientation",), section="10.1"),
    MethodInfo("pm-fk", "agebot-pm", "pm_fk", "ForwardKinematics", ("orientation",), section="10.2"),
    MethodInfo("pm-tilt", "agebot-pm", "pm_tilt", "Tilt", ("tilt",),
               extra_params=("mount_x", "mount_y"), section="10.2 + physical inclinometer"),
)}


def info(name: str) -> MethodInfo:
    try:
        return METHODS[name]
    except KeyError:
        raise CalibrationError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None


def build(name: str, robot, data: MethodData, nominal: np.ndarray, **options):
    """The measurement model of method ``name`` over ``data``.

    nominal: start values of every parameter of the method (robot parameters,
    then the method's extra parameters). options: method-specific keywords
    (e.g. ``residual="squared"``)."""
    mi = info(name)
    if robot.name != mi.robot:
        raise CalibrationError(f"method {name} is for robot {mi.robot}, not {robot.name}")
    cls = getattr(import_module(f"calibration.methods.{mi.module}"), mi.cls)
    kwargs = dict(options)
    if mi.reference is not None:
        kwargs["reference_qm"] = data.reference_qm
    if name == "sm-self-redundancy":
        kwargs["group"] = data.group
    if "distance" in mi.channels:
        kwargs.setdefault("distance_zero", data.distance_zero)
    if name == "pm-fk" and data.components is not None:
        kwargs.setdefault("components", tuple(data.components))
    return cls(robot, data.qm, data.channels, nominal, **kwargs)
