"""Monte Carlo of the reported std at the station's realistic noise
(bench/bench_montecarlo.py prints it, tests/calibration/test_monte_carlo.py
asserts it).

Every run draws a robot around the nominal (``drivers.sim.truth.draw_truth``),
plans and simulates a data set as the trace generator does, with the reading
noise of the simulated station (``fixtures/truth/*-unseen.json``: distance
1e-5 m, angles 1.7e-4 rad per reading) averaged over the session's 5 samples,
and calibrates it with sigma estimated (eq. 51, per channel), as for a session
whose trace gives no sigma. Per identifiable parameter it records the
normalized error ``(x - truth) / std`` and the ratio of the reported std to the
Cramer-Rao bound at the truth for the noise actually applied.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from calibration.errors import CalibrationError
from calibration.methods import METHODS, MethodData, build
from calibration.methods.pm_tilt import heading_grid, ik_modulo_heading
from calibration.methods.sm_distance_tilt import reframe_nominal
from calibration.robots import BUILTIN, get_robot
from calibration.robots.base import canonical_result
from calibration.solver import solve
from drivers.sim.truth import draw_truth
from station.fitting.gate_checks import implausible
from station.fitting.start_values import ROUND_METHODS
from station.simulation.tracegen import generate

SAMPLES = 5  # readings averaged per pose (fixtures/stations/sim-*.toml)
READING = {"distance": 1e-5, "angle": 1.7e-4}  # std of one reading
NOISE = {  # std of one averaged reading per channel
    "sm-distance-tilt": {"distance": READING["distance"] / math.sqrt(SAMPLES),
                         "tilt": READING["angle"] / math.sqrt(SAMPLES)},
    "sm-distance": {"distance": READING["distance"] / math.sqrt(SAMPLES)},
    "pm-fk": {"orientation": READING["angle"] / math.sqrt(SAMPLES)},
    "pm-tilt": {"tilt": READING["angle"] / math.sqrt(SAMPLES)},
}
METHOD_NAMES = tuple(NOISE)
MOUNT_SPREAD = 0.005  # rad, the inclinometer's mounting rotation (pm-tilt)


@dataclass
class Figures:
    """Pooled over runs and identifiable parameters."""

    method: str
    runs: int
    failed: int
    z: np.ndarray  # (runs, N) normalized errors, NaN where not calibrated
    ratio: np.ndarray  # (runs, N) reported std / Cramer-Rao bound
    names: tuple
    # pm-tilt: per run the calibrated IK's worst heading error over +-15 deg / the
    # std the parameter file states for it (not_identified), NaN for other methods
    heading: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    @property
    def heading_rms(self) -> float:
        return float(np.sqrt(np.mean(self.heading ** 2))) if self.heading.size else math.nan

    @property
    def heading_rms_se(self) -> float:
        h2 = self.heading ** 2
        return float(np.std(h2, ddof=1) / math.sqrt(h2.size) / (2 * self.heading_rms))

    @property
    def heading_coverage2(self) -> float:
        return float(np.mean(np.abs(self.heading) < 2)) if self.heading.size else math.nan

    def _flat(self, a):
        return a[np.isfinite(a)]

    @property
    def rms(self) -> float:
        z = self._flat(self.z)
        return float(np.sqrt(np.mean(z * z)))

    @property
    def coverage2(self) -> float:
        return float(np.mean(np.abs(self._flat(self.z)) < 2))

    @property
    def std_over_crb(self) -> float:
        return float(np.median(self._flat(self.ratio)))

    @property
    def rms_se(self) -> float:
        """Standard error of :attr:`rms` from the scatter of the runs' mean z^2
        (the errors within a run are correlated, so runs are the samples)."""
        m = np.nanmean(self.z * self.z, axis=1)
        return float(np.std(m, ddof=1) / math.sqrt(len(m)) / (2 * self.rms))

    @property
    def coverage2_se(self) -> float:
        """Standard error of :attr:`coverage2`, runs as the samples."""
        inside = np.where(np.isfinite(self.z), np.abs(self.z) < 2, np.nan)
        c = np.nanmean(inside, axis=1)
        return float(np.std(c, ddof=1) / math.sqrt(len(c)))

    @property
    def samples(self) -> int:
        return int(np.isfinite(self.z).sum())

    def per_parameter(self):
        """name -> (RMS of z, coverage of 2 std, median std / CRB)."""
        out = {}
        for j, name in enumerate(self.names):
            z = self.z[:, j][np.isfinite(self.z[:, j])]
            if z.size:
                r = self.ratio[:, j][np.isfinite(self.ratio[:, j])]
                out[name] = (float(np.sqrt(np.mean(z * z))), float(np.mean(np.abs(z) < 2)),
                             float(np.median(r)))
        return out


def pm_equivalent(xi, q3_off, k3):
    """The member of the wrist ``xi``'s equivalence family (report eqs. 112-113)
    with the given q3_off, k3: lengths, offsets and gear ratios times ``s``, then
    v and the offsets shifted together. It drives the actuators exactly as ``xi``."""
    xi = np.asarray(xi, float)
    s = k3 / xi[9]
    e = xi * s
    shift = q3_off - s * xi[6]
    e[3] += shift
    e[4:7] += shift
    return e


def one_run(method: str, seed: int, noise: dict | None = None):
    """(names, identifiable mask, x, std, truth vector, CRB, heading z) of one drawn
    robot, or None where the calibration did not converge. heading z (pm-tilt, else
    NaN): worst heading error of the calibrated IK over +-15 deg / its stated std."""
    mi = METHODS[method]
    name = BUILTIN[mi.kind]
    robot = get_robot(name)
    rng = np.random.default_rng(seed)
    noise = NOISE[method] if noise is None else noise
    for _ in range(20):  # a drawn wrist may not reach the whole +-20 deg box: draw again
        truth = draw_truth(name, rng).xi()
        mount = (tuple(rng.uniform(-MOUNT_SPREAD, MOUNT_SPREAD, 2)) if method == "pm-tilt"
                 else (0.0, 0.0))
        try:
            header, ref, poses = generate(method, truth, noise=noise, seed=seed + 1, mount=mount)
            break
        except CalibrationError:
            continue
    else:
        raise CalibrationError(f"no drawn {name} reaches the workspace (seed {seed})")
    channels = {ch: np.array([p[ch] for p in poses]) for ch in mi.channels}
    zero = "exact"
    distance_off = 0.0
    if "distance" in channels:  # the session's draw-wire zero: one noisy averaged reading
        zero = "reading"
        distance_off = float(rng.normal(0.0, noise["distance"]))
        channels["distance"] = channels["distance"] + distance_off
    data = MethodData(qm=np.array([p["qm"] for p in poses]), channels=channels,
                      reference_qm=None if ref is None else np.array(ref["qm"]),
                      distance_zero=zero)
    nominal = np.r_[robot.params(header["nominal"]), np.zeros(len(mi.extra_params))]
    try:
        model = build(method, robot, data, nominal)
        res = solve(model)
    except CalibrationError:  # e.g. the wrist's start cannot assemble: refused, said so
        return None
    if not res.converged or any(res.residual_rms[ch] > 3 * s for ch, s in
                                zip(model.channels, _channel_sigma(model, noise))):
        # no fit, or a local minimum whose residual is not the noise: the
        # station's fit-quality check refuses it; not a statement about the std
        return None
    # as the batch writes it (station.fitting.batch): equivalent forms made one
    res = canonical_result(robot, res, frame_free=method in ROUND_METHODS)
    if implausible(model, res, method, serial=False):
        # the gate's plausibility check refuses it too: gear ratios that changed
        # sign, e.g. the arm mirrored in its plane, which distances alone cannot
        # tell from it (sm-distance: k2, k3, k4 and their zeros negated fit the
        # readings as well as the truth, yet put the tool elsewhere)
        return None
    if method == "sm-distance-tilt":
        tv = reframe_nominal(robot, truth, data.reference_qm)
    elif name == "agebot-pm":
        names = list(res.names)
        tv = pm_equivalent(truth, res.x[names.index("q3_off")], res.x[names.index("k3")])
        if method == "pm-tilt":
            tv = np.r_[tv, mount]
    else:
        tv = truth.copy()
    x = res.x.copy()
    if zero == "reading":
        tv = np.r_[tv, distance_off]
    ok = np.array([s.identifiable for s in res.status])
    if name == "agebot-sm":
        tv = _nearest_equivalent(robot, model, x, res.std, ok, tv)
    # Cramer-Rao bound at the truth for the noise applied (rows weighted 1/sigma^2)
    _, W = model.evaluate(tv)
    sig = _row_sigma(model, noise)
    Wa = W[:, ok] / sig[:, None]
    crb = np.full(len(tv), np.nan)
    crb[ok] = np.sqrt(np.diag(np.linalg.inv(Wa.T @ Wa)))
    heading = math.nan
    if method == "pm-tilt":
        (d,) = model.unidentified_directions(res)
        _, phi = ik_modulo_heading(robot, heading_grid(d["box_deg"]), x[:robot.n_params], truth)
        heading = float(np.abs(phi).max() / d["std_rad"])
    return res.names, ok, x, res.std, tv, crb, heading


# Sign flips of the SM's lengths with half-turn offsets, and half turns of the
# base about the vertical, that can leave a method's predictions unchanged:
# (name, factor) for lengths, (name, turn) for angles. Which hold for a method
# is checked on its model (see _nearest_equivalent).
SM_MIRRORS = (
    {"a0": -1, "theta0": np.pi},
    {"L3": -1, "q3_off": np.pi, "q4_off": -np.pi},
    {"L2": -1, "q2_off": np.pi, "q3_off": -np.pi},
    {"L2": -1, "L4": -1, "q3_off": np.pi, "q4_off": -np.pi, "theta0": np.pi},
    {"L4": -1, "q4_off": np.pi},
)


def _nearest_equivalent(robot, model, x, std, ok, tv):
    """The truth in the equivalent form (:data:`SM_MIRRORS`) nearest the
    solution: the solver may land on a mirror parameterization (a negative
    length), which predicts every reading exactly as the truth does and so is
    the same calibration. Each candidate must give the model's residual at the
    truth to round-off."""
    r0 = model.evaluate(tv)[0]
    best, best_cost = tv, np.inf
    for mask in range(1 << len(SM_MIRRORS)):
        cand = tv.copy()
        for i, mirror in enumerate(SM_MIRRORS):
            if mask >> i & 1:
                for name, v in mirror.items():
                    j = robot.index(name)
                    cand[j] = cand[j] * v if name[0] in "aL" else cand[j] + v
        if mask and not np.allclose(_wrap_angle(model.evaluate(cand)[0] - r0), 0, atol=1e-10):
            continue
        e = _wrap_angle(x - cand)
        cost = float(np.sum(np.where(ok, e / std, 0.0) ** 2))
        if cost < best_cost:
            best, best_cost = cand, cost
    return best


def _wrap_angle(e):
    return e - 2 * np.pi * np.round(e / (2 * np.pi))


def _channel_sigma(model, noise) -> list[float]:
    """Std of one residual row per model channel for the noise applied (channels
    named as the trace's, or per orientation component)."""
    # the wrist's channels are the components of its one reading (orientation, tilt)
    return [noise[ch] if ch in noise else next(iter(noise.values())) for ch in model.channels]


def _row_sigma(model, noise) -> np.ndarray:
    return np.asarray(_channel_sigma(model, noise), float)[np.asarray(model.row_channel)]


def monte_carlo(method: str, runs: int, seed: int = 0, noise: dict | None = None) -> Figures:
    z_rows, r_rows, h_rows, names, failed = [], [], [], None, 0
    for k in range(runs):
        out = one_run(method, seed * 100003 + 7919 * k, noise)
        if out is None:
            failed += 1
            continue
        nm, ok, x, std, tv, crb, heading = out
        names = nm
        if math.isfinite(heading):
            h_rows.append(heading)
        z = np.where(ok, _wrap_angle(x - tv) / std, np.nan)  # angles: a turn away is the same
        z_rows.append(z)
        r_rows.append(np.where(ok, std / crb, np.nan))
    return Figures(method, runs, failed, np.array(z_rows), np.array(r_rows), tuple(names or ()),
                   np.array(h_rows))
