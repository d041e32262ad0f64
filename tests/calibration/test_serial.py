"""Any serial robot from a robot file (report section 2): Jacobians, identifiable
counts, position-only calibration against the Cramer-Rao prediction, parallel
axes in DH and Hayati form, noise-free convergence of every method."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.methods import extra_params
from tests.calibration.serial_helpers import (data_of, fit, identifiable_at, model_of, perturbed,
                                              robot)

METHODS = ("sm-position", "sm-full-pose", "sm-distance", "sm-distance-tilt", "sm-plane",
           "sm-self-redundancy")
ROBOTS = ("ur5-like-dh", "ur5-like-hayati", "scara-like")


def _fd(model, x, h=1e-7):
    J = np.empty((len(model.evaluate(x)[0]), len(x)))
    for j in range(len(x)):
        e = np.zeros(len(x))
        e[j] = h
        rp, rm = model.evaluate(x + e)[0], model.evaluate(x - e)[0]
        d = rp - rm
        J[:, j] = -((d + np.pi) % (2 * np.pi) - np.pi) / (2 * h)  # r = measured - predicted
    return J


@pytest.mark.parametrize("name", ROBOTS)
@pytest.mark.parametrize("method", METHODS)
def test_observation_matrix_matches_finite_differences(name, method):
    rob = robot(name)
    rng = np.random.default_rng(5)
    xi = perturbed(rob, rob.param_names, rng, 0.02)
    data, _ = data_of(rob, method, xi, seed=1, count=8, mount=(0.02, -0.01))
    opts = {"distance_zero": "reading"} if method == "sm-distance-tilt" else {}
    model = model_of(rob, method, data, nominal=xi, **opts)
    assert ("distance_off" in model.names) == (method == "sm-distance-tilt")
    x = model.x0 + 0.01 * rng.uniform(-1, 1, model.x0.size) * np.where(
        [n[0] == "k" for n in model.names], np.abs(model.x0), 1.0)
    W = model.evaluate(x)[1]
    Jn = _fd(model, x)
    for j, n in enumerate(model.names):
        scale = max(np.linalg.norm(Jn[:, j]), 1e-9)
        assert np.linalg.norm(W[:, j] - Jn[:, j]) <= 1e-5 * scale + 1e-7, (name, method, n)


def test_identifiable_counts_and_dh_warning():
    hay, dh = robot("ur5-like-hayati"), robot("ur5-like-dh")
    # 4 n + 6 geometric parameters (eq. 8), the 6 ratios held: 30 from the full pose,
    # 27 from positions (the tool's orientation is not seen)
    assert len(identifiable_at(hay, "sm-full-pose", hay.nominal)) == 30
    assert len(identifiable_at(hay, "sm-position", hay.nominal)) == 27
    # DH on parallel axes 2-3-4: d2, d3, d4 slide along one direction (two dependent)
    pos = identifiable_at(dh, "sm-position", dh.nominal)
    assert len(pos) == 25 and "d3" not in pos and "d4" not in pos
    notes = " ".join(dh.warnings(dh.nominal))
    assert "joints 2 and 3" in notes and "joints 3 and 4" in notes
    assert hay.warnings(hay.nominal) == ()


def _cramer_rao_ratio(rob, xi, res, rng, n=200):
    """Held-out RMS position error of the calibrated model over its Cramer-Rao
    prediction ``sqrt(mean trace(J C J^T) / 3)``."""
    lo, hi = rob.limits[:, 0], rob.limits[:, 1]
    qm = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), size=(n, rob.n_actuators))
    err = rob.fk(qm, res.x[:rob.n_params])[:, :3] - rob.fk(qm, xi)[:, :3]
    act = [res.names.index(c) for c in res.covariance_names]
    J = rob.fk_jacobian(qm, res.x[:rob.n_params])[1][:, :3, :][:, :, act]
    pred = np.einsum("mij,jk,mik->", J, res.covariance, J) / (3 * n)
    return float(np.sqrt(np.mean(err ** 2)) / np.sqrt(pred))


@pytest.mark.parametrize("name,count", [("ur5-like-hayati", 27), ("ur5-like-dh", 25)])
def test_position_calibration_within_cramer_rao(name, count):
    rob = robot(name)
    rng = np.random.default_rng(11)
    xi = perturbed(rob, identifiable_at(rob, "sm-position", rob.nominal), rng, 2e-3)
    data, _ = data_of(rob, "sm-position", xi, seed=3, count=60, noise={"position": 1e-4})
    res = fit(model_of(rob, "sm-position", data), rob, sigma={"x": 1e-4, "y": 1e-4, "z": 1e-4})
    assert res.converged and res.n_identifiable == count
    ratio = _cramer_rao_ratio(rob, xi, res, rng)
    assert 0.5 < ratio < 2.0, ratio


def test_misaligned_parallel_axes_hayati_fits_dh_warns():
    hay, dh = robot("ur5-like-hayati"), robot("ur5-like-dh")
    rng = np.random.default_rng(2)
    xi = perturbed(hay, identifiable_at(hay, "sm-position", hay.nominal), rng, 1e-3)
    xi[hay.index("beta2")] = 2e-3   # axes 2 and 3 not quite parallel
    xi[hay.index("beta3")] = -1.5e-3
    sigma = 5e-5
    data, _ = data_of(hay, "sm-position", xi, seed=4, count=60, noise={"position": sigma})
    res = fit(model_of(hay, "sm-position", data), hay)
    rms = np.sqrt(np.mean(res.residual ** 2))
    assert res.converged and rms < 1.2 * sigma
    m_dh = model_of(dh, "sm-position", data)
    assert any("joints 2 and 3" in n and "Hayati" in n for n in m_dh.notes)
    res_dh = fit(m_dh, dh)
    assert np.sqrt(np.mean(res_dh.residual ** 2)) > 2 * rms  # DH cannot hold the misalignment


@pytest.mark.parametrize("name", ("ur5-like-hayati", "scara-like"))
@pytest.mark.parametrize("method", ("sm-full-pose", "sm-position", "sm-distance",
                                    "sm-distance-tilt", "sm-plane", "sm-self-redundancy"))
def test_noise_free_converges_to_truth(name, method):
    rob = robot(name)
    rng = np.random.default_rng(7)
    count = 40 if method in ("sm-plane", "sm-self-redundancy") else None
    ids = identifiable_at(rob, method, rob.nominal, seed=2, count=count)
    xi = perturbed(rob, ids, rng, 1e-3)
    # parameters that are not identifiable but influence the model must start right
    mount = tuple(0.01 if n in ids else 0.0 for n in ("mount_x", "mount_y"))
    data, header = data_of(rob, method, xi, seed=2, count=count, mount=mount)
    opts, extra = {}, None
    if method == "sm-plane":
        extra = [header["nominal"][k] for k in ("plane_a", "plane_b", "plane_c")]
        opts["plane_given"] = True
    res = fit(model_of(rob, method, data, extra=extra, **opts), rob)
    assert res.converged
    truth = np.r_[xi, mount] if method == "sm-distance-tilt" else xi
    for j, n in enumerate(res.names[:len(truth)]):
        if res.status[j].identifiable:
            assert abs(res.x[j] - truth[j]) < 1e-9 * max(1.0, abs(truth[j])), (n, res.x[j], truth[j])
    assert len(extra_params(method, rob)) == (2 if method == "sm-distance-tilt" else
                                              3 if method == "sm-plane" else 0)


NOISE = {"sm-full-pose": {"pose": [1e-4, 1e-4, 1e-4, 2e-4, 2e-4, 2e-4]},
         "sm-position": {"position": 1e-4}, "sm-distance": {"distance": 1e-4},
         "sm-distance-tilt": {"distance": 1e-4, "tilt": 2e-4}, "sm-plane": {}}
SIGMA_ROWS = {"sm-full-pose": dict(zip(("x", "y", "z", "roll", "pitch", "yaw"),
                                       NOISE["sm-full-pose"]["pose"])),
              "sm-position": {"x": 1e-4, "y": 1e-4, "z": 1e-4}, "sm-distance": {"distance": 1e-4},
              "sm-distance-tilt": {"distance": 1e-4, "roll": 2e-4, "pitch": 2e-4}}


@pytest.mark.slow
@pytest.mark.parametrize("name", ("ur5-like-hayati", "scara-like"))
@pytest.mark.parametrize("method,trials", [("sm-full-pose", 25), ("sm-position", 25),
                                           ("sm-distance", 25), ("sm-distance-tilt", 25),
                                           ("sm-plane", 20)])
def test_monte_carlo_normalized_errors(name, method, trials):
    """Reported std covers the real error: ``(x - truth) / std`` over the identifiable
    parameters has RMS near 1 (known sigma; sm-plane estimates its own)."""
    rob = robot(name)
    rng = np.random.default_rng(17)
    count = 40 if method == "sm-plane" else None
    ids = identifiable_at(rob, method, rob.nominal, seed=2, count=count)
    xi = perturbed(rob, ids, rng, 1e-3)
    mount = tuple(0.01 if n in ids else 0.0 for n in ("mount_x", "mount_y"))
    truth = np.r_[xi, mount] if method == "sm-distance-tilt" else xi
    z = []
    for t in range(trials):
        data, header = data_of(rob, method, xi, seed=100 + t, count=count, mount=mount,
                               noise=NOISE[method])
        opts, extra = {}, None
        if method == "sm-plane":
            # contacts touched with 1e-4 m of noise along the plane's normal
            n = np.array([header["nominal"][k] for k in ("plane_a", "plane_b", "plane_c")])
            extra, opts["plane_given"] = n, True
            p = rob.frames(data.qm, xi)[:, :3, 3]
            p += np.outer(rng.normal(size=len(p)) * 1e-4, n / np.linalg.norm(n))
            qm = np.array([rob.move_to(q, pt, xi) for q, pt in zip(data.qm, p)])
            data = type(data)(qm=qm, channels={})
        res = fit(model_of(rob, method, data, extra=extra, **opts), rob,
                  sigma=SIGMA_ROWS.get(method))
        assert res.converged
        k = [j for j, s in enumerate(res.status[:len(truth)]) if s.identifiable]
        z.extend((res.x[k] - truth[k]) / res.std[k])
    rms = float(np.sqrt(np.mean(np.square(z))))
    assert 0.8 < rms < 1.25, rms


def test_a_drawn_robot_file_truth_calibrates_from_positions():
    """draw_truth on a robot file: free parameters drawn around the nominal, fixed
    ones kept; the position calibration explains the data to the noise."""
    from drivers.sim.truth import draw_truth

    rob = robot("ur5-like-hayati")
    truth = draw_truth(rob.spec, np.random.default_rng(8), offset=0.01, length=0.01)
    xi = truth.xi()
    assert truth.robot == rob.name and all(xi[rob.index(k)] == 1.0 for k in rob.fixed)
    data, _ = data_of(rob, "sm-position", xi, seed=5, count=80, noise={"position": 1e-4})
    res = fit(model_of(rob, "sm-position", data), rob, sigma={"x": 1e-4, "y": 1e-4, "z": 1e-4})
    assert res.converged and res.n_identifiable == 27
    assert np.sqrt(np.mean(res.residual ** 2)) < 1.2e-4
