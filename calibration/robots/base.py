"""What every robot model offers the methods, the planner and the simulator."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from calibration.errors import ConfigError


class RobotModel:
    """A robot's kinematics over its calibrated parameters ``xi``.

    Subclasses set ``name``, ``param_names``, ``nominal`` (report's nominal),
    ``true`` (report's true values), ``coords`` (names of the generalized
    coordinates X), ``n_actuators`` and implement :meth:`fk` and :meth:`ik`.
    """

    name: str
    kind: str = "serial"  # what methods it takes (calibration.methods.MethodInfo.kind)
    fixed: tuple[str, ...] = ()  # parameters held at their nominal values
    param_names: tuple[str, ...]
    nominal: np.ndarray
    true: np.ndarray
    coords: tuple[str, ...]
    n_actuators: int
    #: parameters that are angles (rad): compared modulo 2 pi, written wrapped to (-pi, pi]
    angle_params: tuple[str, ...] = ()

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def index(self, name: str) -> int:
        try:
            return self.param_names.index(name)
        except ValueError:
            raise ConfigError(f"unknown parameter {name!r} for robot {self.name} "
                              f"(known: {', '.join(self.param_names)})", key=name) from None

    def params(self, values: Mapping[str, float] | None = None, base=None,
               *, source: str | None = None) -> np.ndarray:
        """Parameter vector from a name -> value mapping; names not given take
        ``base`` (default: the nominal values). Unknown names are an error."""
        xi = np.array(self.nominal if base is None else base, dtype=float)
        for k, v in (values or {}).items():
            try:
                i = self.param_names.index(k)
            except ValueError:
                raise ConfigError(f"unknown parameter {k!r} for robot {self.name}",
                                  source=source, key=k) from None
            try:
                xi[i] = float(v)
            except (TypeError, ValueError):
                raise ConfigError(f"value {v!r} is not a number", source=source, key=k) from None
            if not np.isfinite(xi[i]):
                raise ConfigError(f"value {v!r} is not finite", source=source, key=k)
        return xi

    def as_dict(self, xi) -> dict[str, float]:
        return {n: float(v) for n, v in zip(self.param_names, xi)}

    def position_jacobian(self, qm, xi):
        """``(p (m, 3), dp/dxi (m, 3, N))``: the tool position and its rows of the
        generalized Jacobian (serial robots)."""
        X, psi = self.fk_jacobian(qm, xi)
        return X[:, :3], psi[:, :3, :]

    def canonical(self, xi, frame_free: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The same robot in the parameters' one written form: angles (``angle_params``)
        wrapped to ``(-pi, pi]``. Returns ``(xi', s)`` with ``s (N,)`` the derivative
        ``d xi' / d xi`` (+-1 per parameter), so that a covariance becomes ``s C s``.
        frame_free: the method's measurements do not see the base frame's turn about
        its vertical axis (robots may then have more equivalent forms)."""
        xi = np.array(xi, dtype=float)
        for name in self.angle_params:
            i = self.index(name)
            xi[i] = wrap_half_open(xi[i])
        return xi, np.ones(len(xi))

    def fk(self, qm, xi):  # pragma: no cover - interface
        """Generalized coordinates ``(m, len(coords))`` for actuator values ``qm (m, n)``."""
        raise NotImplementedError

    def ik(self, X, xi, **options):  # pragma: no cover - interface
        """Actuator values for one pose X; raises UnreachablePose where there is none."""
        raise NotImplementedError


def wrap_half_open(a):
    """Angles wrapped to ``(-pi, pi]`` (the parameter file's range)."""
    return -((np.pi - np.asarray(a, dtype=float)) % (2 * np.pi) - np.pi)


def canonical_result(robot: RobotModel, result, frame_free: bool = False):
    """``result`` (:class:`calibration.solver.CalibrationResult`) with the robot's
    parameters in their canonical form (:meth:`RobotModel.canonical`); the
    covariance follows. Parameters of the method (extra names) are unchanged."""
    import dataclasses

    n = robot.n_params
    xr, sign = robot.canonical(result.x[:n], frame_free)
    x = np.r_[xr, result.x[n:]]
    s_all = dict(zip(robot.param_names, sign))
    s = np.array([s_all.get(name, 1.0) for name in result.covariance_names])
    cov = np.asarray(result.covariance) * np.outer(s, s) if s.size else result.covariance
    return dataclasses.replace(result, x=x, covariance=cov)
