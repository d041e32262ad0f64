"""The general DH chain: geometric Jacobian against finite differences, the
parameter count of eq. 8, and identifiability with full pose measurement."""
import numpy as np
import pytest

from calibration.dh_model import DHJoint, dh_model
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


# -- the vectorized evaluation against a plain per-pose reference --------------
def _elementary(kind, v):
    c, s = np.cos(v), np.sin(v)
    E = np.eye(4)
    axis = "xyz".index(kind[1])
    if kind[0] == "t":
        E[axis, 3] = v
    else:
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        E[i, i], E[i, j], E[j, i], E[j, j] = c, -s, s, c
    return E


def _reference(chain, qm, xi):
    """Per pose, per factor: the frames as products of 4x4 matrices and the
    Jacobian accumulated factor by factor (eqs. 16-24), written plainly."""
    q = chain.joints(qm, xi)
    Ts, psis, befores = [], [], []
    for qi, qmi in zip(q, np.atleast_2d(qm)):
        T, before = np.eye(4), []
        for f in chain.factors:
            before.append(T)
            v = f.const + sum(c * xi[i] for i, c in f.terms)
            v += 0.0 if f.joint is None else qi[f.joint]
            T = T @ _elementary(f.kind, v)
        psi, jq = np.zeros((6, chain.n_params)), np.zeros((6, chain.n_joints))
        for f, B in zip(chain.factors, before):
            u = B[:3, "xyz".index(f.kind[1])]
            col = (np.r_[u, 0, 0, 0] if f.kind[0] == "t"
                   else np.r_[np.cross(u, T[:3, 3] - B[:3, 3]), u])
            for i, c in f.terms:
                psi[:, i] += c * col
            if f.joint is not None:
                jq[:, f.joint] += col
        for jt, (io, ig) in enumerate(zip(chain.offset_idx, chain.gain_idx)):
            if io >= 0:
                psi[:, io] += jq[:, jt]
            if ig >= 0:
                psi[:, ig] += jq[:, jt] * qmi[jt]
        Ts.append(T)
        psis.append(psi)
        befores.append(before)
    return np.array(Ts), np.array(psis), np.array(befores)


def _general_chain():
    """Every factor kind, Hayati's Rot(y), several terms per factor, a joint
    with a parameter term and joints without offset or gain parameters."""
    from calibration.chain import Chain, Factor

    fs = (Factor("ry", 0.1, ((0, 1.5), (1, -0.5))), Factor("tx", joint=0),
          Factor("ty", 0.2, ((2, 1.0),)), Factor("rz", 0.3, ((3, 0.7),), joint=1),
          Factor("rx", -0.4, ((1, 1.0),)), Factor("ry", joint=2), Factor("tz", 0.3),
          Factor("ty", joint=1))
    return Chain(fs, 6, (4, -1, -1), (5, -1, -1))


@pytest.mark.parametrize("case", ["RRRRRR", "PRRR", "RPRP", "R", "general"])
@pytest.mark.parametrize("m", [1, 3, 50])
def test_vectorized_kinematics_equal_per_pose_reference(case, m):
    rng = np.random.default_rng([m, len(case)])
    if case == "general":
        chain, xi = _general_chain(), rng.normal(0, 0.5, 6)
    else:
        model = random_model(case, rng)
        chain, xi = model.chain, model.nominal + rng.normal(0, 0.01, len(model.nominal))
    qm = rng.uniform(-2, 2, (m, chain.n_joints))
    T_ref, psi_ref, before_ref = _reference(chain, qm, xi)
    T, psi = chain.jacobian(qm, xi)
    np.testing.assert_allclose(T, T_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chain.fk(qm, xi), T_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(psi, psi_ref, rtol=0, atol=1e-12)
    T_p, psi_p = chain.jacobian(qm, xi, position_only=True)
    np.testing.assert_allclose(psi_p, psi_ref[:, :3], rtol=0, atol=1e-12)
    Tf, before = chain.frames(qm, xi)
    np.testing.assert_allclose(before, before_ref, rtol=0, atol=1e-12)
    cols = chain.factor_columns(Tf, before)
    jq = chain.joint_jacobian(qm, xi)
    for jt in range(chain.n_joints):  # J(Q): the columns of the factors a joint moves
        moved = [j for j, f in enumerate(chain.factors) if f.joint == jt]
        np.testing.assert_allclose(jq[:, :, jt], cols[:, :, moved].sum(axis=2), atol=1e-12)


def test_general_chain_jacobian_matches_finite_differences():
    chain, rng = _general_chain(), np.random.default_rng(8)
    xi, qm = rng.normal(0, 0.5, 6), rng.uniform(-2, 2, (4, 3))
    _, psi = chain.jacobian(qm, xi)
    h = 1e-6
    for j in range(6):
        d = np.zeros(6)
        d[j] = h
        Tp, Tm = chain.fk(qm, xi + d), chain.fk(qm, xi - d)
        dp = (Tp[:, :3, 3] - Tm[:, :3, 3]) / (2 * h)
        dw = np.array([rotvec_between(Tp[i, :3, :3], Tm[i, :3, :3]) for i in range(4)]) / (2 * h)
        np.testing.assert_allclose(psi[:, :3, j], dp, atol=1e-7)
        np.testing.assert_allclose(psi[:, 3:, j], dw, atol=1e-7)
