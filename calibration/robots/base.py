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

    def fk(self, qm, xi):  # pragma: no cover - interface
        """Generalized coordinates ``(m, len(coords))`` for actuator values ``qm (m, n)``."""
        raise NotImplementedError

    def ik(self, X, xi, **options):  # pragma: no cover - interface
        """Actuator values for one pose X; raises UnreachablePose where there is none."""
        raise NotImplementedError
