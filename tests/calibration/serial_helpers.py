"""Robot files for the calibration tests: models, data sets and truths."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from calibration import identifiability as ident
from calibration.methods import MethodData, build, extra_params
from calibration.robots import get_robot
from calibration.solver import SolverOptions, solve
from drivers.robot_file import load_robot_file
from station.simulation.tracegen_serial import generate

ROBOTS = Path(__file__).resolve().parents[2] / "fixtures" / "robots"


def robot(name: str):
    return get_robot(load_robot_file(ROBOTS / f"{name}.toml"))


def data_of(rob, method, xi, *, seed=0, noise=None, count=None, mount=(0.0, 0.0), plane=None):
    """``(MethodData, header)`` of a simulated data set of ``rob`` with truth ``xi``
    (sm-plane: the true plane in the header's nominal)."""
    known = ("plane_a", "plane_b", "plane_c") if method == "sm-plane" else ()
    header, ref, poses = generate(rob, method, xi, seed=seed, noise=noise, count=count,
                                  mount=mount, plane=plane, known=known)
    chans = {}
    for ch in ("position", "pose", "distance", "tilt"):
        if ch in poses[0]:
            chans[ch] = np.array([p[ch] for p in poses], dtype=float)
    group = np.array([p["group"] for p in poses]) if "group" in poses[0] else None
    return MethodData(qm=np.array([p["qm"] for p in poses]), channels=chans, group=group,
                      reference_qm=None if ref is None else np.array(ref["qm"])), header


def model_of(rob, method, data, nominal=None, extra=None, **opts):
    """The measurement model; ``nominal`` of the robot's parameters (default its nominal),
    ``extra`` the method's extra start values (default 0)."""
    ex = extra_params(method, rob)
    nom = np.r_[rob.nominal if nominal is None else nominal,
                np.zeros(len(ex)) if extra is None else extra]
    return build(method, rob, data, nom, **opts)


def fit(model, rob, sigma=None):
    return solve(model, SolverOptions(fixed=tuple(rob.fixed), sigma=sigma))


def identifiable_at(rob, method, xi, *, seed=0, count=None, plane=None):
    """Names identifiable for ``method`` at ``xi`` (noise-free data of ``xi``)."""
    data, _ = data_of(rob, method, xi, seed=seed, count=count, plane=plane)
    model = model_of(rob, method, data, nominal=xi)
    twin = model.consistent_twin(model.x0)
    W = twin.evaluate(model.x0)[1]
    cand = np.array([n not in rob.fixed for n in model.names])
    st = ident.analyze(W, model.names, candidates=cand)
    return [s.name for s in st if s.identifiable]


def perturbed(rob, names, rng, scale=1e-3):
    """The nominal with the robot parameters ``names`` moved by ``scale`` (relative for
    ratios k)."""
    xi = rob.nominal.copy()
    for n in names:
        if n in rob.param_names:
            j = rob.index(n)
            xi[j] += scale * rng.uniform(-1, 1) * (abs(xi[j]) if n[0] == "k" else 1.0)
    return xi
