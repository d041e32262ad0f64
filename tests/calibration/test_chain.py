"""The general DH chain: geometric Jacobian against finite differences, the
parameter count of eq. 8, and identifiability with full pose measurement."""
import numpy as np
import pytest

from calibration.chain import DHJoint, dh_model
from tests.calibration.helpers import assert_columns_close, rotvec_between


def random_model(kinds, rng):
    joints = [DHJoint(k, d=rng.uniform(-0.3, 0.3), theta=rng.uniform(-1, 1),
                      a=rng.uniform(0.1, 0.6), alpha=rng.uniform(-1.2, 1.2)) for k in kinds]
    return dh_model(joints, base=tuple(rng.uniform(-0.5, 0.5, 4)), tool=tuple(rng.uniform(-0.3, 0.3, 2)),
                    gains=list(rng.uniform(0.5, 2.0, len(kinds))))


@pytest.mark.parametrize("kinds", ["RRRRRR", "PRRR", "RPRP", "R"])
def test_jacobian_matches_finite_differences(kinds):
    rng = np.random.default_rng(len(kinds))
    model = random_model(kinds, rng)
    chain = model.chain
    qm = rng.uniform(-1, 1, (5, len(kinds)))
    T, psi = chain.jacobian(qm, model.nominal)
    h = 1e-6
    num = np.zeros_like(psi)
    for j in range(chain.n_params):
        d = np.zeros(chain.n_params)
        d[j] = h
        Tp, Tm = chain.fk(qm, model.nominal + d), chain.fk(qm, model.nominal - d)
        num[:, :3, j] = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        num[:, 3:, j] = np.array([rotvec_between(Tp[i, :3, :3], Tm[i, :3, :3])
                                  for i in range(len(qm))]) / (2 * h)
    assert_columns_close(psi[:, :3], num[:, :3], names=model.names)
    assert_columns_close(psi[:, 3:], num[:, 3:], names=model.names)


@pytest.mark.parametrize("kinds", ["RRRRRR", "PRRR", "RRPR"])
def test_parameter_count_is_eq_8_plus_transmission(kinds):
    model = random_model(kinds, np.random.default_rng(0))
    n_r, n_p = kinds.count("R"), kinds.count("P")
    assert model.n_geometric == 4 * n_r + 2 * n_p + 6
    assert len(model.names) == model.n_geometric + len(kinds)


def test_general_6r_chain_fully_identifiable_from_full_pose():
    rng = np.random.default_rng(3)
    model = random_model("RRRRRR", rng)
    qm = rng.uniform(-2, 2, (40, 6))
    _, psi = model.chain.jacobian(qm, model.nominal)
    W = psi.reshape(-1, model.chain.n_params)
    W = W / np.linalg.norm(W, axis=0)
    sv = np.linalg.svd(W, compute_uv=False)
    assert sv[-1] / sv[0] > 1e-6, "the 4n+6 (+n) parameters of eq. 8 should be independent"


def test_joint_transmission_roundtrip():
    model = random_model("RPR", np.random.default_rng(5))
    qm = np.array([[0.3, -0.2, 1.0]])
    q = model.chain.joints(qm, model.nominal)
    np.testing.assert_allclose(model.chain.actuators(q, model.nominal), qm)
