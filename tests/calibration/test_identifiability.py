"""The method table of docs/models.md: non-identifiable parameters, their influence
class and N_R, as the solver reports them at the solution."""
import pytest

from calibration.solver import solve
from tests.calibration.helpers import dataset

NONE, INFL = "no influence", "influences the model"
TABLE = {
    "sm-full-pose": ({}, 13),
    "sm-distance": ({"q1_off": NONE, "q2_off": NONE, "theta0": NONE, "a0": NONE}, 9),
    "sm-self-redundancy": ({"q1_off": NONE, "q2_off": NONE, "k1": NONE, "theta0": NONE,
                            "a0": NONE, "L4": INFL}, 7),
    "sm-plane": ({"L4": INFL, "theta0": INFL, "a0": INFL, "plane_a": INFL, "plane_b": INFL,
                  "plane_c": INFL}, 10),
    "sm-distance-tilt": ({}, 13),
}


@pytest.mark.parametrize("method", list(TABLE))
def test_brief_table(method):
    expected, n_r = TABLE[method]
    model, _ = dataset(method, seed=4)
    res = solve(model)
    assert res.converged, res.message
    got = {s.name: s.label for s in res.status if not s.identifiable}
    assert got == expected
    assert res.n_identifiable == n_r


@pytest.mark.parametrize("method", ["sm-self-redundancy", "sm-plane"])
def test_constraint_dependencies_found_before_iterating(method):
    """The scale of self-calibration and the plane's translation are exact only
    where the model fits the data: the solver analyses a consistent twin of the
    data first, so L4 never starts moving (which would let the arm collapse)."""
    model, _ = dataset(method, seed=5)
    res = solve(model)
    first = res.history[0].x
    i = model.names.index("L4")
    assert first[i] == model.x0[i]


def test_analysis_at_nominal_alone_finds_too_few():
    from calibration import identifiability as ident

    model, _ = dataset("sm-self-redundancy", seed=6)
    _, W = model.evaluate(model.x0)
    at_nominal = {s.name for s in ident.analyze(W, model.names) if not s.identifiable}
    assert "L4" not in at_nominal and "q2_off" not in at_nominal


@pytest.mark.parametrize("method,n_r", [("sm-distance", 10), ("sm-distance-tilt", 14)])
def test_a_zero_that_is_a_reading_adds_one_identifiable_parameter(method, n_r):
    """The draw-wire zeroed on a noisy reading: ``distance_off`` is calibrated and
    identifiable with distance alone (7.2) as with distance + tilt (7.5); the
    table above (docs/models.md's) is the exact zero (no ``distance_off``)."""
    model, _ = dataset(method, seed=4, distance_zero="reading", distance_off=3e-5)
    res = solve(model)
    assert res.converged, res.message
    assert res.names[-1] == "distance_off" and res.status[-1].identifiable
    assert res.n_identifiable == n_r
    expected = TABLE[method][0]
    assert {s.name: s.label for s in res.status if not s.identifiable} == expected


def test_a_constant_tilt_offset_is_a_frame_rotation():
    """An inclinometer reading every tilt ``delta`` too high is explained exactly by
    ``q2_off + delta`` and ``theta0 + delta`` (the base frame turned about the rail
    through the origin): a frame convention, not a parameter (docs/methods.md)."""
    model, truth = dataset("sm-distance-tilt", seed=3)
    delta = 0.01
    model.phi_m = model.phi_m + delta
    x = truth.copy()
    x[model.names.index("q2_off")] += delta
    x[model.names.index("theta0")] += delta
    assert abs(model.residuals(truth)).max() > 0.9 * delta
    assert abs(model.residuals(x)).max() < 1e-12


def _unit(rows: int, seed: int = 0):
    import numpy as np

    return np.linalg.qr(np.random.default_rng(seed).normal(size=(rows, rows)))[0]


def test_a_dependency_a_calibration_bent_keeps_the_nominal_s_set():
    """Three translations of one link and a fourth along joint i's axis: at the nominal the
    axis is the first of them exactly and the second of two equal columns goes; a
    milliradian off (a calibrated URDF read again), the sequential QR would keep the
    nearly parallel pair and drop the third, at a coefficient of a thousand. The exchange
    keeps the nominal's set, whose condition stays of order one."""
    import numpy as np

    from calibration.identifiability import classify

    e = _unit(40)[:, :3]
    for eps in (0.0, 1e-3, 1e-5):
        along = e[:, 0] + eps * e[:, 2]  # joint i's axis, eps off joint i+1's x
        W = np.column_stack([along, e[:, 0], e[:, 1], e[:, 2]]) * [0.3, 2.0, 2.0, 2.0]
        ok, dep, rdiag, _ = classify(W)
        assert ok.tolist() == [True, False, True, True], (eps, ok)
        assert dep.tolist() == [False, True, False, False]
        kept = W[:, ok] / np.linalg.norm(W[:, ok], axis=0)
        assert np.linalg.cond(kept) < 10
        assert rdiag[1] <= 10 * eps + 1e-12  # the one left out: its distance from the kept


def test_columns_each_clearly_apart_but_together_dependent_lose_one():
    """A Kahan triangle: every column at least 0.04 from the span of the earlier ones, the
    smallest singular value 2e-11. One column goes (the last that takes part), the rest
    are conditioned as the rank tolerance asks."""
    import numpy as np

    from calibration.identifiability import classify

    n, c = 100, 0.25
    s = np.sqrt(1 - c * c)
    K = np.diag(s ** np.arange(n)) @ (np.triu(-c * np.ones((n, n)), 1) + np.eye(n))
    W = _unit(300)[:, :n] @ K
    ok, dep, rdiag, _ = classify(W)
    assert ok.sum() == n - 1 and dep.sum() == 1
    kept = W[:, ok] / np.linalg.norm(W[:, ok], axis=0)
    assert np.linalg.svd(kept, compute_uv=False)[-1] > 1e-8
