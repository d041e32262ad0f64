"""The platform's orientation as AGEBOT's parallel wrist writes it (report section 2.2):
the rotation of XYZ Euler angles, the angles of a rotation, the map from the angles'
rates to the angular velocity, and the cross-product matrix."""
from __future__ import annotations

import numpy as np


def rot_xyz(X) -> np.ndarray:
    """``R = Rx(alpha) Ry(beta) Rz(gamma)`` for ``X (m, 3)``: ``(m, 3, 3)``."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    ca, sa = np.cos(X[:, 0]), np.sin(X[:, 0])
    cb, sb = np.cos(X[:, 1]), np.sin(X[:, 1])
    cg, sg = np.cos(X[:, 2]), np.sin(X[:, 2])
    R = np.empty((X.shape[0], 3, 3))
    R[:, 0, 0] = cb * cg
    R[:, 0, 1] = -cb * sg
    R[:, 0, 2] = sb
    R[:, 1, 0] = sa * sb * cg + ca * sg
    R[:, 1, 1] = -sa * sb * sg + ca * cg
    R[:, 1, 2] = -sa * cb
    R[:, 2, 0] = -ca * sb * cg + sa * sg
    R[:, 2, 1] = ca * sb * sg + sa * cg
    R[:, 2, 2] = ca * cb
    return R


def euler_xyz(R) -> np.ndarray:
    """``X = [alpha, beta, gamma] (m, 3)`` of rotations ``R (m, 3, 3)`` (the inverse of
    :func:`rot_xyz` for ``|beta| < 90 deg``)."""
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    return np.stack([np.arctan2(-R[:, 1, 2], R[:, 2, 2]),
                     np.arcsin(np.clip(R[:, 0, 2], -1.0, 1.0)),
                     np.arctan2(-R[:, 0, 1], R[:, 0, 0])], axis=-1)


def euler_rates(X) -> np.ndarray:
    """``H(X) (m, 3, 3)`` of eq. 118: angular velocity = H * d[alpha, beta, gamma]."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    ca, sa = np.cos(X[:, 0]), np.sin(X[:, 0])
    cb, sb = np.cos(X[:, 1]), np.sin(X[:, 1])
    H = np.zeros((X.shape[0], 3, 3))
    H[:, 0, 0] = 1.0
    H[:, 0, 2] = sb
    H[:, 1, 1] = ca
    H[:, 1, 2] = -sa * cb
    H[:, 2, 1] = sa
    H[:, 2, 2] = ca * cb
    return H


def _skew(v: np.ndarray) -> np.ndarray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2] = -v[..., 2], v[..., 1]
    S[..., 1, 0], S[..., 1, 2] = v[..., 2], -v[..., 0]
    S[..., 2, 0], S[..., 2, 1] = -v[..., 1], v[..., 0]
    return S
