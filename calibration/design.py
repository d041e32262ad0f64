"""Pose design: which poses to measure, and what accuracy they will give.

Pure numerics on a measurement model (:class:`calibration.model.MeasurementModel`)
built over a *pool* of candidate poses that the planner found reachable and safe:

* :func:`pose_information` splits the pool's error-weighted observation matrix
  ``G W`` (identifiable columns, as the report's QR analysis finds them) into one
  block of rows per candidate (a pose, or a group of poses that must be measured
  together, e.g. a sm-self-redundancy pair);
* :func:`d_optimal` chooses ``count`` candidates that maximize
  ``log det(sum_i B_i^T B_i)`` (D-optimality: the smallest volume of the
  parameters' confidence ellipsoid, the smallest geometric mean of their
  standard deviations), by a greedy start and Fedorov's exchange;
* :func:`cramer_rao` predicts the standard deviation of every identifiable
  parameter that a plan will give (the Cramer-Rao bound ``(W^T Sigma^-1 W)^-1``,
  eq. 52 evaluated before measuring), :func:`observability` the indices O1 and O3
  of Sun and Hollerbach (2008) on the column-scaled matrix, and
  :func:`propagate` the predicted std of any quantity linear in the parameters
  (e.g. the held-out tool position);
* :func:`grow_until` adds the most informative candidates until a predicted
  accuracy is reached.

D-optimality does not depend on the units of the parameters (scaling a column
scales the determinant by a constant), so the blocks are scaled by the pool's
column norms only for numerical health.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibration import identifiability as ident
from calibration.errors import CalibrationError
from calibration.ties import first_max

#: relative ridge that keeps the greedy start's information matrix invertible
RIDGE = 1e-9


@dataclass(frozen=True)
class PoseInformation:
    """The information each candidate carries about the identifiable parameters.

    names:   identifiable parameter names (the pool's structural analysis).
    columns: their indices among the model's parameters.
    blocks:  ``(candidates, rows, L)`` rows of ``G W[:, columns]`` per candidate,
             zero-padded where candidates have fewer rows; ``G = 1/sigma`` per row.
    scale:   ``(L,)`` column norms of the pool's ``G W`` (the scaled blocks are
             ``blocks / scale``).
    members: candidate -> the pool's pose indices it stands for.
    """

    names: tuple[str, ...]
    columns: np.ndarray
    blocks: np.ndarray
    scale: np.ndarray
    members: tuple[np.ndarray, ...]

    @property
    def size(self) -> int:
        return len(self.blocks)

    @property
    def scaled(self) -> np.ndarray:
        return self.blocks / self.scale

    def matrix(self, chosen, scaled: bool = False) -> np.ndarray:
        """Information matrix ``sum_i B_i^T B_i`` over the ``chosen`` candidates."""
        B = (self.scaled if scaled else self.blocks)[np.asarray(chosen, dtype=int)]
        B = B.reshape(-1, B.shape[-1])
        return B.T @ B

    def poses(self, chosen) -> np.ndarray:
        """The pool's pose indices of the ``chosen`` candidates, in their order."""
        return np.concatenate([self.members[i] for i in chosen]) if len(chosen) else \
            np.zeros(0, dtype=int)


def row_sigma(model, sigma: dict | None) -> np.ndarray:
    """Std of every row of ``model`` from ``sigma`` (row channel -> std; 1 where absent)."""
    sigma = sigma or {}
    s = np.array([float(sigma.get(ch, 1.0)) for ch in model.channels])
    if np.any(~np.isfinite(s)) or np.any(s <= 0):
        raise CalibrationError("every channel's noise must be a positive number")
    return s[np.asarray(model.row_channel, dtype=int)]


def pose_information(model, x, sigma: dict | None = None, *, group=None,
                     names=None) -> PoseInformation:
    """Per-candidate information of ``model`` (built over the pool) at parameters ``x``.

    sigma: row channel -> std of one reading (the method's noise).
    group: ``(n_poses,)`` candidates of poses that are measured together, or None
           (each pose its own candidate).
    names: the parameters to design for; default the identifiable ones of the pool
           (the report's QR analysis with the noise weights), less the robot's ``fixed``."""
    x = np.asarray(x, dtype=float)
    twin = model.consistent_twin(x)
    _, W = twin.evaluate(x)
    g = 1.0 / row_sigma(twin, sigma)
    if names is None:
        fixed = set(getattr(getattr(model, "robot", None), "fixed", ()) or ())
        cand = np.array([n not in fixed for n in model.names]) if fixed else None
        status = ident.analyze(W, model.names, weights=g, candidates=cand,
                               order=model.identify_order)
        cols = np.array([j for j, s in enumerate(status) if s.identifiable], dtype=int)
    else:
        cols = np.array([list(model.names).index(n) for n in names], dtype=int)
    if len(cols) == 0:
        raise CalibrationError("no parameter is identifiable from the candidate poses")
    GW = W[:, cols] * g[:, None]
    n_poses = int(twin.n_poses)
    rows = GW.shape[0]
    if n_poses < 1 or rows % n_poses:
        raise CalibrationError(f"{model.method}: {rows} rows do not split into {n_poses} poses")
    p = rows // n_poses
    per_pose = GW.reshape(n_poses, p, len(cols))
    if group is None:
        members = tuple(np.array([i]) for i in range(n_poses))
        blocks = per_pose
    else:
        group = np.asarray(group)
        keys = list(dict.fromkeys(group.tolist()))
        members = tuple(np.flatnonzero(group == k) for k in keys)
        width = max(len(m) for m in members) * p
        blocks = np.zeros((len(members), width, len(cols)))
        for u, m in enumerate(members):
            b = per_pose[m].reshape(-1, len(cols))
            blocks[u, :len(b)] = b
    scale = np.linalg.norm(GW, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    return PoseInformation(tuple(model.names[j] for j in cols), cols, blocks, scale, members)


def _logdet(M) -> float:
    sign, ld = np.linalg.slogdet(M)
    return float(ld) if sign > 0 else -np.inf


def _gains(B: np.ndarray, Minv: np.ndarray) -> np.ndarray:
    """``log det(I + B_u M^-1 B_u^T)`` for every candidate block ``B_u``: written out
    for blocks of one row (a distance: ``log(1 + b M^-1 b^T)``) and of two (distance
    and tilt: the 2 x 2 determinant), where a stack of small ``slogdet`` calls cost
    more than the products."""
    n, p, k = B.shape
    rows = B.reshape(n * p, k)
    BM = rows @ Minv                           # one product for every row (BLAS)
    if p == 1:
        s = np.einsum("ij,ij->i", BM, rows)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(s > -1.0, np.log1p(s), -np.inf)
    S = BM.reshape(n, p, k) @ B.transpose(0, 2, 1)      # B_u M^-1 B_u^T
    S += np.eye(p)
    if p == 2:
        det = S[:, 0, 0] * S[:, 1, 1] - S[:, 0, 1] * S[:, 1, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(det > 0, np.log(det), -np.inf)
    sign, ld = np.linalg.slogdet(S)
    return np.where(sign > 0, ld, -np.inf)


def d_optimal(info: PoseInformation, count: int, *, fixed=(), exchange: bool = True,
              max_sweeps: int = 30) -> np.ndarray:
    """``count`` candidates (indices into ``info``) of maximal ``log det`` information.

    fixed: candidates that are in the plan whatever happens (already measured);
    they count toward ``count`` and are never exchanged. Greedy start (each
    step the candidate of largest gain, by the matrix determinant lemma), then
    Fedorov's exchange: swap a chosen candidate for an unchosen one while that
    raises the determinant."""
    fixed = [int(i) for i in fixed]
    if count > info.size:
        raise CalibrationError(f"{count} poses asked from a pool of only {info.size} candidates")
    if count < len(fixed):
        raise CalibrationError("fewer poses asked than are already measured")
    B = info.scaled
    chosen, free, M = _greedy(info, fixed, lambda chosen: len(chosen) >= count)
    if exchange:
        ld = _logdet(M)
        for _ in range(max_sweeps):
            improved = False
            for pos in range(len(fixed), len(chosen)):
                i = chosen[pos]
                M_minus = M - B[i].T @ B[i]
                ld_minus = _logdet(M_minus)
                if not np.isfinite(ld_minus):
                    continue
                gains = _gains(B, np.linalg.inv(M_minus))
                gains[~free] = -np.inf
                j = first_max(gains)       # a near tie: the first (calibration/ties.py)
                if ld_minus + gains[j] > ld + 1e-10 * max(1.0, abs(ld)):
                    chosen[pos] = j
                    free[i], free[j] = True, False
                    M = M_minus + B[j].T @ B[j]
                    ld = _logdet(M)
                    improved = True
            if not improved:
                break
    return np.array(chosen, dtype=int)


def covariance(info: PoseInformation, chosen) -> np.ndarray:
    """Predicted covariance of the identifiable parameters for the ``chosen``
    candidates (inf on the diagonal where the plan cannot identify them)."""
    Ms = info.matrix(chosen, scaled=True)
    try:
        c = np.linalg.cholesky(Ms)
    except np.linalg.LinAlgError:
        return np.full((len(info.names),) * 2, np.inf)
    ci = np.linalg.inv(c)
    cov_s = ci.T @ ci
    return cov_s / np.outer(info.scale, info.scale)


def cramer_rao(info: PoseInformation, chosen) -> np.ndarray:
    """Predicted std of every identifiable parameter (``info.names`` order)."""
    return np.sqrt(np.diag(covariance(info, chosen)))


def observability(info: PoseInformation, chosen) -> dict:
    """Sun and Hollerbach's observability indices of the ``chosen`` candidates on
    the column-scaled weighted matrix: ``O1 = (s_1 ... s_L)^(1/L) / sqrt(m)``
    (D-optimality), ``O3 = s_L`` (the smallest singular value, E-optimality),
    and the condition number ``s_1 / s_L``."""
    B = info.scaled[np.asarray(chosen, dtype=int)]
    A = B.reshape(-1, B.shape[2])
    s = np.linalg.svd(A, compute_uv=False)
    m = len(info.poses(chosen))
    if s[-1] <= 0:
        return {"O1": 0.0, "O3": 0.0, "condition_number": np.inf}
    return {"O1": float(np.exp(np.mean(np.log(s))) / np.sqrt(max(m, 1))), "O3": float(s[-1]),
            "condition_number": float(s[0] / s[-1])}


def geometric_mean_std(std: np.ndarray) -> float:
    std = np.asarray(std, dtype=float)
    return float(np.exp(np.mean(np.log(std)))) if np.all(std > 0) else 0.0


def propagate(J: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Predicted std of quantities ``y = J dx`` (``J: (rows, L)``): ``sqrt(diag(J C J^T))``."""
    J = np.atleast_2d(J)
    return np.sqrt(np.maximum(np.einsum("rl,rl->r", J @ cov, J), 0.0))


def _greedy(info: PoseInformation, start, done):
    """Add the candidate of largest D-gain to ``start`` until ``done(chosen)``; returns
    ``(chosen, free, M)``: the list, the mask of unchosen candidates and the scaled
    information matrix (with the ridge)."""
    B = info.scaled
    chosen = [int(i) for i in start]
    free = np.ones(info.size, dtype=bool)
    free[chosen] = False
    M = RIDGE * np.eye(B.shape[2]) + (info.matrix(chosen, scaled=True) if chosen else 0.0)
    while not done(chosen):
        gains = _gains(B, np.linalg.inv(M))
        gains[~free] = -np.inf
        j = first_max(gains)
        chosen.append(j)
        free[j] = False
        M = M + B[j].T @ B[j]
    return chosen, free, M


def grow_until(info: PoseInformation, met, *, start=(), limit: int | None = None) -> np.ndarray:
    """Add candidates (each the largest D-gain) to ``start`` until ``met(cov)`` is
    true for the predicted covariance; returns the chosen candidates. Raises
    :class:`CalibrationError` when the whole pool (or ``limit``) is not enough."""
    limit = info.size if limit is None else min(limit, info.size)

    def done(chosen):
        if chosen and met(covariance(info, chosen)):
            return True
        if len(chosen) >= limit:
            raise CalibrationError(f"even {len(chosen)} poses are not predicted to reach the "
                                   f"asked accuracy; widen the workspace or relax the target")
        return False

    return np.array(_greedy(info, start, done)[0], dtype=int)


def fk_jacobian(fk, qm, x, columns, step: float = 1e-7) -> np.ndarray:
    """``d fk(qm, x) / d x[columns]`` by central differences: ``(m, coords, L)``.

    fk: ``fk(qm, x) -> (m, coords)`` (a robot model's forward kinematics)."""
    x = np.asarray(x, dtype=float)
    out = []
    for j in columns:
        h = step * max(1.0, abs(x[j]))
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        out.append((np.asarray(fk(qm, xp)) - np.asarray(fk(qm, xm))) / (2 * h))
    return np.stack(out, axis=-1)
