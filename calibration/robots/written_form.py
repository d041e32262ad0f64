"""What a written form of a serial chain tells the one model of it.

A serial chain (:class:`calibration.robots.serial.SerialRobot`) is written either as a
robot file's DH/Hayati joints (:mod:`calibration.robots.dh_form`) or as a URDF's chain
(:mod:`calibration.robots.urdf`). Its spec (pure data, what a driver reads) names its
:class:`WrittenForm` through its ``form`` property; the form says how the spec becomes
the model's pieces. A third written form is one more such module: a spec, its layout
and its chain.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from calibration.chain import Chain


def as_written(spec) -> tuple[str, ...]:
    """The held parameters a spec writes (``spec.fixed``)."""
    return tuple(spec.fixed)


def transmission_chain(factors, names: tuple[str, ...], n_joints: int,
                       compliance: bool = False) -> Chain:
    """The :class:`Chain` of ``factors`` over the parameters ``names``, every written
    form's joint i driven as eq. 9: ``q_i = k{i} * qm_i + q{i}_off`` (``+ c{i} * tau_i``
    with ``compliance``)."""
    ix = {n: j for j, n in enumerate(names)}
    js = range(1, n_joints + 1)
    return Chain(tuple(factors), len(names), offset_idx=tuple(ix[f"q{i}_off"] for i in js),
                 gain_idx=tuple(ix[f"k{i}"] for i in js),
                 comp_idx=tuple(ix[f"c{i}"] for i in js) if compliance else ())


@dataclass(frozen=True)
class WrittenForm:
    """How a spec of one written form becomes the model of its chain.

    layout:     ``layout(spec) -> [(name, nominal), ...]`` every parameter, in the
                model's order (the unpivoted QR keeps the earlier of two dependent ones).
    chain:      ``chain(spec, names) -> Chain`` the elementary factors over ``names``
                (:func:`transmission_chain`).
    held:       ``held(spec) -> names`` held at their nominal values unless freed.
    warnings:   ``warnings(robot, xi, tol) -> (str, ...)`` conditioning notes, or None.
    loads:      ``loads(robot, qm) -> tau (m, n) | None`` what bends the joints, or None.
    operations: ``{name: f(robot, ...)}`` what only this form's models offer (methods of
                the model; ``hasattr(robot, name)`` tells the forms apart: a URDF's
                ``calibrated_origins``, ``frame_matrix``, ``held_reason``, ``joint_label``).
    """

    layout: Callable[[Any], list[tuple[str, float]]]
    chain: Callable[[Any, tuple[str, ...]], Any]
    held: Callable[[Any], tuple[str, ...]] = as_written
    warnings: Callable[..., tuple[str, ...]] | None = None
    loads: Callable[..., Any] | None = None
    operations: Mapping[str, Callable[..., Any]] = field(default_factory=dict)
