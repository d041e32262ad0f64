"""Shared builders for the calibration tests: noise-free or noisy data sets
made by the same generator the station uses for its fixtures."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calibration.methods import METHODS, MethodData, build
from calibration.robots import BUILTIN, get_robot
from station.simulation.tracegen import generate

KNOWN = {"sm-self-redundancy": ("L4",),
         "sm-plane": ("L4", "theta0", "a0", "plane_a", "plane_b", "plane_c")}


def dataset(method, *, seed=0, noise=None, known=None, truth=None, count=None, components=None,
            distance_zero="exact", distance_off=0.0):
    """(model, truth vector in the model's parameters) for a generated data set.

    distance_zero, distance_off: the distance methods' draw-wire zero (``"reading"``:
    ``distance_off`` calibrated, appended to the truth vector) and the offset (m)
    that every distance reading carries."""
    mi = METHODS[method]
    robot = get_robot(BUILTIN[mi.kind])
    xi = robot.true if truth is None else np.asarray(truth, float)
    known = KNOWN.get(method, ()) if known is None else known
    header, ref, poses = generate(method, xi, noise=noise, seed=seed, known=known, count=count,
                                  components=components)
    nom = dict(header["nominal"])
    extra = [nom.pop(k, 0.0) for k in mi.extra_params]
    nominal = np.r_[robot.params(nom), extra]
    channels = {ch: np.array([p[ch] for p in poses]) for ch in mi.channels}
    if "distance" in channels:
        channels["distance"] = channels["distance"] + distance_off
    data = MethodData(qm=np.array([p["qm"] for p in poses]), channels=channels,
                      distance_zero=distance_zero,
                      group=np.array([p["group"] for p in poses]) if "group" in poses[0] else None,
                      reference_qm=None if ref is None else np.array(ref["qm"]),
                      components=components)
    opts = {}
    if method == "sm-plane":
        opts["plane_given"] = all(k in header["nominal"] for k in mi.extra_params)
    model = build(method, robot, data, nominal, **opts)
    truth_vec = np.r_[xi, extra] if method == "sm-plane" else xi.copy()
    if method == "sm-distance-tilt":
        from calibration.methods.sm_distance_tilt import reframe_nominal

        truth_vec = reframe_nominal(robot, xi, data.reference_qm)
    if distance_zero == "reading":
        truth_vec = np.r_[truth_vec, distance_off]
    return model, truth_vec


def fd_jacobian(f, x, h=1e-6):
    """Central differences of ``f (N,) -> (rows,)``."""
    x = np.asarray(x, float)
    cols = []
    for j in range(len(x)):
        step = h * max(1.0, abs(x[j]))
        d = np.zeros_like(x)
        d[j] = step
        cols.append((f(x + d) - f(x - d)) / (2 * step))
    return np.column_stack(cols)


def rotvec_between(R1, R0):
    """Rotation vector of ``R1 R0^T`` (small rotations)."""
    return Rotation.from_matrix(R1 @ R0.T).as_rotvec()


def assert_columns_close(J, J_ref, rtol=1e-6, floor=1e-9, names=None):
    """Each Jacobian column (last axis; the other axes are its rows) equals the
    reference's within ``rtol`` of the reference column's own norm, so a small
    column is checked as tightly as a large one (one global tolerance would let a
    3 % error in a short geometric column pass). ``floor`` (relative to the
    largest reference column) is the round-off allowance of the finite
    differences, and all a column that should be zero may have."""
    J, J_ref = np.asarray(J, float), np.asarray(J_ref, float)
    assert J.shape == J_ref.shape, (J.shape, J_ref.shape)
    n = J.shape[-1]
    A, B = J.reshape(-1, n), J_ref.reshape(-1, n)
    ref = np.linalg.norm(B, axis=0)
    err = np.linalg.norm(A - B, axis=0)
    allowed = rtol * ref + floor * max(float(ref.max(initial=0.0)), 1e-300)
    bad = np.flatnonzero(~(err <= allowed))
    if bad.size:
        label = (lambda j: names[j]) if names is not None else str
        raise AssertionError("Jacobian columns differ: " + "; ".join(
            f"{label(j)}: |error| {err[j]:.3g} = {err[j] / ref[j] if ref[j] else np.inf:.2g} of "
            f"its norm {ref[j]:.3g} (allowed {allowed[j]:.3g})" for j in bad))
