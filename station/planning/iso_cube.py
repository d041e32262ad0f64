"""The ISO 9283 test cube of a URDF robot measured by a point instrument (docs/accuracy.md).

The cube (:mod:`calibration.iso9283`: its corners, the measuring plane C1-C2-C7-C8, the
points P1..P5) has its edges along the axes of the robot's base link frame, as the
standard places it, and the tool keeps one orientation at all its points: that of a pose
the instrument sees well (a candidate, below). It *fits* where

* the nominal model reaches the five measuring points at that orientation (the tool:
  the centre of the calibrated points on the tool, turned as the nominal program's tool
  is) within the joint limits less :data:`~station.planning.marker_plan.MARGIN` of each
  range (and the station config's limits): the *nominal program*, each point solved
  from the one before it; and the tool's point reaches each of the cube's eight corners
  (at any orientation: the cube is inside the workspace, the test measures the plane);
* the calibrated model reaches the five measuring points from there: the *compensated
  program* (:class:`calibration.compensation.SerialCompensation`, as ``app.py
  compensate`` computes it);
* at every measuring pose of both programs every point on the tool is visible to the
  instrument (:func:`~station.planning.marker_plan.visible`: inside its volume, facing
  its viewpoint) as the calibration places the instrument and the points;
* the tip stays :data:`~station.planning.serial_plan.FLOOR_MARGIN` above the floor at
  every pose, and every move of a cycle (P2 to P1, P1 to P5, ...) clear of it
  (:func:`~station.planning.serial_plan.path_clear`).

The largest cube (:func:`largest_cube`): the tool's orientations and points of
:data:`CANDIDATES` poses drawn where the instrument sees every point are the candidates'
orientations and centres; each one's edge is the largest that fits (bisection from
:data:`SIZES`), and the largest of them is the test's. A cube given by the engineer
(:func:`given_cube`) is tried at the orientations of the :data:`NEAREST` candidates
nearest its centre; where none fits it is refused, naming what did not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration import iso9283
from calibration.compensation import SerialCompensation
from calibration.errors import CalibrationError
from calibration.methods.sm_markers import marker_count, marker_names
from station.outputs.iso9283 import view_frame
from station.planning import marker_plan
from station.planning.serial_plan import FLOOR_MARGIN, PATH_MARGIN, path_clear

CANDIDATES = 24          # candidate orientations and centres of the largest cube
SIZES = (0.02, 1.6)      # m: the smallest edge tried and the largest
BISECT = 9               # halvings of the edge between them (1.6 m / 512: 3 mm)
NEAREST = 12             # a given cube: the candidates nearest its centre tried
#: the corners each is solved from (index into P1..P5 of :data:`calibration.iso9283.POINTS`)
CORNER_START = (1, 2, 0, 0, 0, 0, 3, 4)


@dataclass
class TestModel:
    """What the test is planned with: the robot, the compensation (the calibrated model
    and tool, base link frame), the nominal inverse kinematics (the nominal model and
    tool; ``reach``: its point alone), the calibrated instrument frame ``frame (4, 4)`` (the base link in the
    instrument's frame) and parameters with it ``x_view``, the calibrated points on the
    tool ``points (M, 3)`` (tip link frame), the instrument's ``sight`` and the joints'
    ``box (n, 2)``."""

    robot: object
    comp: SerialCompensation
    nominal: SerialCompensation
    reach: SerialCompensation
    frame: np.ndarray
    x_view: np.ndarray
    points: np.ndarray
    sight: marker_plan.Sight
    box: np.ndarray


@dataclass
class Cube:
    """A test cube that fits (module doc): ``centre (3,)`` m and ``size`` m in the base
    link frame (edges along its axes), the tool's orientation ``tool (3, 3)``, the five
    ``targets (5, 4, 4)`` (P1..P5, base link frame) and the programs ``q_nom``,
    ``q_comp`` ``(5, n)`` that reach them (nominal, calibrated model)."""

    centre: np.ndarray
    size: float
    tool: np.ndarray
    targets: np.ndarray
    q_nom: np.ndarray
    q_comp: np.ndarray


def test_model(s, doc: dict, sight, qm_range=None) -> TestModel:
    """The :class:`TestModel` of a parameter file's content ``doc`` and its compensation
    ``s`` (:func:`station.outputs.compensate.setup` of a URDF robot's ``sm-markers``)."""
    robot, comp = s.robot, s.comp
    params = doc["parameters"]
    x_view, frame = view_frame(robot, params, comp.xi_cal)
    names = marker_names(marker_count(params))
    points = np.array([float(params[nm]["value"]) for nm in names]).reshape(-1, 3)
    box = marker_plan.limit_box(robot, qm_range)
    nominal = SerialCompensation(robot, comp.xi_nom, comp.xi_nom, tool_nom=comp.tool_nom,
                                 tool_cal=comp.tool_nom, orientation=comp.orientation,
                                 limits=box)
    reach = SerialCompensation(robot, comp.xi_nom, comp.xi_nom, tool_nom=comp.tool_nom,
                               tool_cal=comp.tool_nom, orientation=False, limits=box)
    return TestModel(robot, comp, nominal, reach, frame, x_view, points, sight, box)


def _targets(points, tool) -> np.ndarray:
    T = np.tile(np.eye(4), (len(points), 1, 1))
    T[:, :3, :3] = tool
    T[:, :3, 3] = points
    return T


def fit_cube(tm: TestModel, centre, size: float, tool, q0) -> Cube | str:
    """The :class:`Cube` of edge ``size`` about ``centre`` with the tool at ``tool`` (its
    nominal program solved from ``q0``), or why it does not fit, in words."""
    c = np.asarray(centre, dtype=float)
    P = iso9283.measuring_points(c, size)
    T = _targets(P, tool)
    q_nom = np.zeros((5, tm.robot.n_actuators))
    here = np.asarray(q0, dtype=float)
    for name in iso9283.CYCLE:              # each point solved from the one before it
        k = iso9283.POINTS.index(name)
        sol = tm.nominal.solve(here, T[k])
        if not sol.ok:
            return f"{name} is out of the nominal robot's reach there ({sol.reason})"
        q_nom[k] = here = sol.qm
    C = _targets(iso9283.cube_corners(c, size), tool)
    q_corner = np.zeros((8, tm.robot.n_actuators))
    for i in range(8):
        sol = tm.reach.solve(q_nom[CORNER_START[i]], C[i])
        if not sol.ok:
            return f"its corner C{i + 1} is out of the robot's reach ({sol.reason})"
        q_corner[i] = sol.qm
    q_comp = np.zeros_like(q_nom)
    lo, hi = tm.box[:, 0], tm.box[:, 1]
    for k in range(5):
        sol = tm.comp.solve(q_nom[k], T[k])
        if not sol.ok:
            return f"{iso9283.POINTS[k]} is out of the calibrated robot's reach ({sol.reason})"
        if np.any(sol.qm < lo - 1e-9) or np.any(sol.qm > hi + 1e-9):
            j = int(np.argmax((sol.qm < lo - 1e-9) | (sol.qm > hi + 1e-9)))
            return (f"{iso9283.POINTS[k]}'s compensated joint {j + 1} is beyond the test's "
                    "limits")
        q_comp[k] = sol.qm
    for prog, q in (("nominal", q_nom), ("compensated", q_comp)):
        seen = marker_plan.visible(tm.robot, tm.x_view, tm.points, tm.sight, q)
        if not seen.all():
            k, j = np.argwhere(~seen)[0]
            return (f"point {j + 1} on the tool is not seen by the instrument at "
                    f"{iso9283.POINTS[k]} ({prog} program)")
    base = tm.comp.xi_cal
    z = tm.robot.frames(np.vstack([q_nom, q_comp, q_corner]), base)[:, 2, 3]
    if np.any(z < FLOOR_MARGIN):
        return f"the tool comes within {FLOOR_MARGIN} m of the floor"
    order = [iso9283.POINTS.index(n) for n in iso9283.CYCLE + iso9283.CYCLE[:1]]
    for q in (q_nom, q_comp):
        if not all(path_clear(tm.robot, base, q[a], q[b]) for a, b in zip(order, order[1:])):
            return f"a move of the cycle comes within {PATH_MARGIN} m of the floor"
    return Cube(c, float(size), np.asarray(tool, dtype=float), T, q_nom, q_comp)


def candidates(tm: TestModel, rng, count: int = CANDIDATES):
    """``(q (k, n), tool frames (k, 4, 4))``: poses drawn in the test's box where every
    point is visible, and the nominal tool's frame there (base link frame)."""
    q, tally = marker_plan.draw(tm.robot, tm.x_view, tm.points, tm.sight, tm.box, rng,
                                marker_plan.POOL)
    if not len(q):
        raise marker_plan.too_few(tm.robot, tally, 0, 1)
    q = q[:count]
    return q, tm.nominal.targets(q)


def _largest_at(tm: TestModel, q, T, least: float = SIZES[0]) -> Cube | str:
    """The largest cube about ``T``'s point at its orientation (``q``: where the nominal
    program starts), of edge ``least`` at least, or why not even that."""
    lo, hi = least, SIZES[1]
    best = fit_cube(tm, T[:3, 3], lo, T[:3, :3], q)
    if isinstance(best, str):
        return best
    for _ in range(BISECT):
        mid = 0.5 * (lo + hi)
        got = fit_cube(tm, T[:3, 3], mid, T[:3, :3], q)
        if isinstance(got, str):
            hi = mid
        else:
            best, lo = got, mid
    return best


def largest_cube(tm: TestModel, rng, count: int = CANDIDATES) -> Cube:
    """The largest cube that fits about the candidates' tool points (module doc)."""
    qs, Ts = candidates(tm, rng, count)
    best, why = None, ""
    for q, T in zip(qs, Ts):
        got = _largest_at(tm, q, T, SIZES[0] if best is None else best.size)
        if isinstance(got, str):
            why = why or got
        elif best is None or got.size > best.size:
            best = got
    if best is None:
        raise CalibrationError(f"no test cube of {SIZES[0] * 1e3:.0f} mm fits about {len(qs)} "
                               f"poses where the instrument sees the tool: {why}")
    return best


def given_cube(tm: TestModel, centre, size: float, rng) -> Cube:
    """The cube of edge ``size`` about ``centre`` (m, base link frame) at the orientation of
    one of the :data:`NEAREST` candidates nearest to it; CalibrationError in one line
    where none fits, naming why at the nearest."""
    qs, Ts = candidates(tm, rng, marker_plan.POOL)
    c = np.asarray(centre, dtype=float)
    near = np.argsort(np.linalg.norm(Ts[:, :3, 3] - c, axis=1))[:NEAREST]
    why = None
    for i in near:
        got = fit_cube(tm, c, size, Ts[i, :3, :3], qs[i])
        if not isinstance(got, str):
            return got
        why = why or got
    at = ", ".join(f"{v * 1e3:.0f}" for v in c)
    raise CalibrationError(f"the test cube of edge {size * 1e3:.0f} mm about ({at}) mm does "
                           f"not fit: {why} (tried at the tool orientations of the "
                           f"{len(near)} poses nearest it where the instrument sees the "
                           "tool); leave --cube out for the largest that fits")
