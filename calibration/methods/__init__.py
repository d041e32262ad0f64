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
    """kind: the kind of robot the method needs (``RobotModel.kind``): ``"serial"``
    (agebot-sm and every robot file) or ``"parallel-wrist"`` (agebot-pm)."""

    name: str
    kind: str
    module: str
    cls: str
    channels: tuple[str, ...]  # trace channels the method reads
    reference: str | None = None  # role of the reference record it needs
    extra_params: tuple[str, ...] = ()
    section: str = ""
    file_cls: str | None = None  # the class for a robot file, where it differs
    file_extra: tuple[str, ...] = ()  # extra parameters on a robot file
    urdf_only: bool = False  # needs a URDF robot (its instrument frame is a free rigid frame)


def is_robot_file(robot) -> bool:
    """Whether ``robot`` (a model) comes from a robot file (not a built-in)."""
    return getattr(robot, "spec", None) is not None


def extra_params(name: str, robot, markers: int = 0) -> tuple[str, ...]:
    """The method's parameters after the robot's, on ``robot`` (a model); sm-markers
    has three per point on the tool (``markers`` of them)."""
    mi = info(name)
    if name == "sm-markers":
        from calibration.methods.sm_markers import marker_names

        return marker_names(markers)
    return mi.extra_params + (mi.file_extra if is_robot_file(robot) else ())


METHODS: dict[str, MethodInfo] = {m.name: m for m in (
    MethodInfo("sm-full-pose", "serial", "sm_full_pose", "FullPose", ("pose",), section="7.1"),
    MethodInfo("sm-position", "serial", "sm_position", "Position", ("position",),
               section="7.1, position only (a laser tracker's reflector)"),
    MethodInfo("sm-distance", "serial", "sm_distance", "Distance", ("distance",),
               reference="reference-point", section="7.2"),
    MethodInfo("sm-self-redundancy", "serial", "sm_self_redundancy", "SelfRedundancy", (),
               section="7.3"),
    MethodInfo("sm-plane", "serial", "sm_plane", "Plane", (),
               extra_params=("plane_a", "plane_b", "plane_c"), section="7.4"),
    MethodInfo("sm-distance-tilt", "serial", "sm_distance_tilt", "DistanceTilt",
               ("distance", "tilt"), reference="base-origin", section="7.5",
               file_cls="InclinometerDistanceTilt", file_extra=("mount_x", "mount_y")),
    MethodInfo("pm-ik", "parallel-wrist", "pm_ik", "InverseKinematics", ("orientation",), section="10.1"),
    MethodInfo("pm-fk", "parallel-wrist", "pm_fk", "ForwardKinematics", ("orientation",), section="10.2"),
    MethodInfo("pm-tilt", "parallel-wrist", "pm_tilt", "Tilt", ("tilt",),
               extra_params=("mount_x", "mount_y"), section="10.2 + physical inclinometer"),
    MethodInfo("sm-markers", "serial", "sm_markers", "Markers", ("markers",),
               section="7.1, points on the tool in the instrument's frame (a tracker's "
                       "reflectors, motion-capture markers)", urdf_only=True),
)}


def info(name: str) -> MethodInfo:
    try:
        return METHODS[name]
    except KeyError:
        raise CalibrationError(f"unknown method {name!r} (known: {', '.join(METHODS)})") from None


def is_urdf_robot(robot) -> bool:
    """Whether ``robot`` (a model) is a URDF robot's chain."""
    return hasattr(robot, "calibrated_origins")


def check_kind(name: str, robot) -> None:
    """CalibrationError unless method ``name`` takes ``robot`` (its kind)."""
    mi = info(name)
    if robot.kind != mi.kind:
        raise CalibrationError(f"method {name} needs a {mi.kind} robot; {robot.name} is "
                               f"a {robot.kind} one")
    if mi.urdf_only and not is_urdf_robot(robot):
        raise CalibrationError(f"method {name} takes a URDF robot (--robot FILE.urdf "
                               f"--base-link B --tip-link T); {robot.name} is not one")


def methods_for(robot) -> tuple[str, ...]:
    """The methods that take ``robot`` (a model), in registry order."""
    return tuple(n for n, mi in METHODS.items() if mi.kind == robot.kind
                 and (is_urdf_robot(robot) or not mi.urdf_only))


def build(name: str, robot, data: MethodData, nominal: np.ndarray, **options):
    """The measurement model of method ``name`` over ``data``.

    nominal: start values of every parameter of the method (robot parameters,
    then the method's extra parameters). options: method-specific keywords
    (e.g. ``residual="squared"``)."""
    mi = info(name)
    check_kind(name, robot)
    cls_name = mi.file_cls if (mi.file_cls and is_robot_file(robot)) else mi.cls
    cls = getattr(import_module(f"calibration.methods.{mi.module}"), cls_name)
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
