"""A simulated URDF robot's session (``sm-markers``) scored against its truth
(:mod:`station.simulation.urdf_sessions`, ``bench/bench_urdf_sessions.py``).

The calibrated parameters are not compared with the truth's one by one: the points on the
tool and some joint parameters trade off (the unidentifiable combinations are held at
their start values, and the calibrated ones absorb them), so two parameter sets that
differ can predict the same. What the session must get right is what it observes: where
the points on the tool are, in the instrument's frame, with the robot anywhere in its
joint limits. So at ``count`` poses drawn (seeded) inside the joint limits, for every
point on the tool:

* the error ``e (3,)``: the calibrated model's prediction (the parameter file's values,
  the held ones included) minus the truth's (:func:`drivers.sim.urdf_truth.true_points`);
* its reported covariance ``J C J^T``: ``C`` the parameter file's covariance over the
  calibrated parameters, ``J`` the sm-markers model's Jacobian of the point's position
  with respect to them (:class:`calibration.methods.sm_markers.Markers`, the session's
  own model, evaluated at the calibrated values);
* ``d2 = e^T (J C J^T)^-1 e``: chi-square on 3 for an honest covariance. ``d2 / 3`` is
  the whitened error per coordinate; its RMS over poses and points (1 for an honest
  std) and the share within the 95 % ellipsoid (``d2 <= chi2_3(0.95)``, 95 %) say how
  honest the reported std of the predictions is.

As the robot file's arm's (:mod:`station.simulation.session_scores`), the errors of one
session move together (one data set): a session's whitened RMS over many poses is one
draw, and the pooled figures take the sessions as the samples. Also kept: the held-out
error the session printed (the gate's validation: the held-out points' 3D RMS after
calibration, m).

Nothing here is used by a real station; it needs the simulator.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: poses at which a session's predictions are compared with the truth
COUNT = 200
#: chi-square on 3 degrees of freedom at 95 %: the 95 % ellipsoid of a point's error
CHI2_3_95 = 7.814727903251178


@dataclass
class UrdfScore:
    """One scored URDF session.

    completed: the session ran to its parameter file; ``error`` says why not, ``refused``
               whether that was the station's named refusal (a StationError).
    poses, skipped, events: recorded poses, skipped ones, event kind -> count.
    heldout:   the held-out points' 3D RMS after calibration the session printed (m;
               ``heldout_before`` with the start values).
    e, cov, d2: ``(K, M, 3)`` errors of the predicted points (m), ``(K, M, 3, 3)`` their
               reported covariance, ``(K, M)`` the Mahalanobis ``e^T cov^-1 e``.
    """

    seed: int
    completed: bool
    error: str = ""
    refused: bool = False
    poses: int = 0
    skipped: int = 0
    events: dict = field(default_factory=dict)
    seconds: float = math.nan
    heldout: float = math.nan
    heldout_before: float = math.nan
    e: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3)))
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 3, 3)))
    d2: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))

    @property
    def whitened_rms(self) -> float:
        """RMS of the whitened error per coordinate, ``sqrt(mean(d2 / 3))`` (1 honest)."""
        return float(np.sqrt(np.mean(self.d2 / 3.0))) if self.d2.size else math.nan

    @property
    def coverage95(self) -> float:
        """Share of the points' errors inside their 95 % ellipsoid."""
        return float(np.mean(self.d2 <= CHI2_3_95)) if self.d2.size else math.nan

    @property
    def error_rms(self) -> float:
        """RMS 3D distance (m) of the predicted points from the true ones."""
        return float(np.sqrt(np.mean(np.sum(self.e ** 2, axis=-1)))) if self.e.size else math.nan

    @property
    def std_rms(self) -> float:
        """RMS of the reported 3D std of the predicted points (m)."""
        if not self.cov.size:
            return math.nan
        return float(np.sqrt(np.mean(np.trace(self.cov, axis1=-2, axis2=-1))))


def calibrated_points(doc: dict):
    """``(robot, x, names)`` of a parameter file of sm-markers: the nominal robot of its
    robot file, the calibrated values of the robot's parameters then the points on the
    tool (``marker{j}_x ...``), and those names."""
    from calibration.methods.sm_markers import marker_count, marker_names
    from station.outputs.export import calibrated_model

    if doc.get("method") != "sm-markers":
        raise ValueError(f"the parameter file is of {doc.get('method')}, not sm-markers")
    robot, xi = calibrated_model(doc)
    names = marker_names(marker_count(doc["parameters"]))
    x = np.r_[xi, [float(doc["parameters"][n]["value"]) for n in names]]
    return robot, x, tuple(robot.param_names) + names


def score_poses(robot, count: int = COUNT, seed: int = 0) -> np.ndarray:
    """``(count, n)`` joint values drawn uniformly inside the joint limits (seeded)."""
    lo, hi = robot.limits[:, 0], robot.limits[:, 1]
    return np.random.default_rng(seed).uniform(lo, hi, size=(count, len(lo)))


def predictions(doc: dict, qm) -> tuple[np.ndarray, np.ndarray]:
    """``(p (K, M, 3), cov (K, M, 3, 3))``: the points on the tool the parameter file
    ``doc`` predicts at ``qm`` (m, the instrument's frame) and their reported covariance
    ``J C J^T`` (module doc)."""
    from calibration.methods import MethodData, build

    robot, x, names = calibrated_points(doc)
    qm = np.atleast_2d(np.asarray(qm, dtype=float))
    M = (len(x) - robot.n_params) // 3
    model = build("sm-markers", robot, MethodData(qm=qm, channels={"markers":
                                                                   np.zeros((len(qm), M, 3))}), x)
    if tuple(model.names) != names:
        raise ValueError("the sm-markers model's parameters are not the parameter file's")
    r, W = model.evaluate(x)             # r = readings (0) - prediction, W = d prediction / dx
    p = -r.reshape(len(qm), M, 3)
    cov_names = list(doc["covariance"]["names"])
    C = np.asarray(doc["covariance"]["matrix"], dtype=float)
    J = W[:, [names.index(n) for n in cov_names]].reshape(len(qm), M, 3, len(cov_names))
    return p, np.einsum("kmia,ab,kmjb->kmij", J, C, J)


def truth_points(truth, qm) -> np.ndarray:
    """``(K, M, 3)`` the truth's points on the tool at ``qm`` (m, the instrument's frame)."""
    from drivers.sim.urdf_truth import true_points

    model, xi = truth.model(), truth.xi()
    return np.array([true_points(truth, model, xi, q) for q in np.atleast_2d(qm)])


def heldout(doc: dict) -> tuple[float, float]:
    """The held-out points' 3D RMS after and before calibration the session printed (m;
    the gate's validation check), NaN where the file has none."""
    for c in doc.get("fit", {}).get("quality", {}).get("checks", ()):
        if c.get("check") == "validation" and "rms_after" in c:
            return float(c["rms_after"]), float(c.get("rms_before", math.nan))
    return math.nan, math.nan


def score_document(score: UrdfScore, doc: dict, truth, *, count: int = COUNT,
                   seed: int = 0) -> UrdfScore:
    """``score`` with the parameter file ``doc`` judged against ``truth`` at ``count``
    poses drawn with ``seed`` (module doc)."""
    from calibration.methods.sm_markers import marker_count

    if marker_count(doc["parameters"]) != len(truth.points):
        raise ValueError(f"the parameter file has {marker_count(doc['parameters'])} points on "
                         f"the tool, the truth {len(truth.points)}")
    robot, _, _ = calibrated_points(doc)
    qm = score_poses(robot, count, seed)
    p, cov = predictions(doc, qm)
    score.e = p - truth_points(truth, qm)
    score.cov = cov
    score.d2 = np.einsum("kmi,kmi->km", score.e, np.linalg.solve(cov, score.e[..., None])[..., 0])
    score.heldout, score.heldout_before = heldout(doc)
    return score


def score_file(params_path, truth, **kw) -> UrdfScore:
    """A finished session's parameter file (``params.json``, read and verified) scored
    against ``truth`` (a :class:`~drivers.sim.truth.SimTruth` or its file)."""
    from drivers.sim.truth import load_truth
    from station.outputs.params_file import read_params

    if not hasattr(truth, "points"):
        truth = load_truth(truth)
    return score_document(UrdfScore(seed=truth.seed or 0, completed=True),
                          read_params(params_path), truth, **kw)


def summary(scores: list[UrdfScore]) -> dict:
    """Sessions, refused and failed ones; over the completed sessions' points: the
    whitened RMS (its standard error with the sessions as the samples), the coverage of
    the 95 % ellipsoid, the RMS error and reported std of the predicted points (m), the
    mean held-out error (m) the sessions printed."""
    done = [s for s in scores if s.completed and s.d2.size]
    d2 = np.concatenate([s.d2.reshape(-1) for s in done]) if done else np.zeros(0)
    rms = float(np.sqrt(np.mean(d2 / 3.0))) if d2.size else math.nan
    rms_se = math.nan
    if len(done) > 1:       # each session's mean d2/3 one sample; delta method for the sqrt
        per = np.array([np.mean(s.d2 / 3.0) for s in done])
        rms_se = float(np.std(per, ddof=1) / math.sqrt(len(per)) / (2 * rms))
    return {"sessions": len(scores), "completed": sum(s.completed for s in scores),
            "refused": sum(s.refused for s in scores),
            "failed": sum(not s.completed and not s.refused for s in scores),
            "whitened_rms": rms, "whitened_rms_se": rms_se,
            "coverage95": float(np.mean(d2 <= CHI2_3_95)) if d2.size else math.nan,
            "per_session_whitened": [s.whitened_rms for s in done],
            "error_rms": (float(np.sqrt(np.mean([s.error_rms ** 2 for s in done])))
                          if done else math.nan),
            "std_rms": (float(np.sqrt(np.mean([s.std_rms ** 2 for s in done])))
                        if done else math.nan),
            "heldout_mean": (float(np.nanmean([s.heldout for s in done]))
                             if done else math.nan)}
