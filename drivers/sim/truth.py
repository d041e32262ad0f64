"""The simulator truth file: what the simulated robot really is (file-formats.md).

A JSON object, so that a test can hand the simulator values the code has never
seen::

    {"robot": "agebot-sm" | "agebot-pm",   # "urdf": drivers/sim/urdf_truth.py
     "parameters": {name: value, ...},   # every parameter of the robot model,
                                         # names as in docs/models.md;
                                         # agebot-sm may add plane_a, plane_b, plane_c
                                         # (all three): the plane a x + b y + c z + 1 = 0
     "noise": {channel: std, ...},       # optional, std of ONE reading:
                                         #   distance [m], tilt/roll/pitch/yaw [rad],
                                         #   qm [actuator units]; absent = 0
     "seed": 7,                          # optional, seed of the simulator's noise
     "inclinometer_mount": [rx, ry],     # optional, agebot-pm only: the inclinometer's
                                         # mounting rotation on the platform,
                                         # R_mount = Rx(rx) Ry(ry), rad (default 0, 0)
     "repeatability": {"backlash": 2e-5, "positioning": 5e-6},
                                         # optional (default: none, the link is where
                                         # the motor is), see below
     "comment": "..."}                   # optional, free text

A robot file's truth (docs/robot-files.md, "Truth files of a robot file") adds
``"robot_file": "<path to the TOML>"`` (relative to the truth file) and ``"robot"``
is the file's name; names left out of ``parameters`` take the file's nominal;
``inclinometer_mount`` is the tool inclinometer's; noise also takes ``position`` [m] and ``pose``
(a number or 6 values: m, m, m, rad, rad, rad).

``repeatability`` (any robot, a URDF robot's too) makes the simulated drives position
as a real robot's do (:mod:`drivers.sim.axis`): ``backlash`` is each joint's whole play
(rad; m for a prismatic joint or the rail: the link's position approached from above
and from below differs by this), ``positioning`` the std of a random error of the link
at the end of each move (rad, m); each one number for every joint or a list of one per
joint, each at most 0.01 (:mod:`drivers.sim.repeatability`). The drives' encoders do
not see either (they are between the motor and the link); the random error is drawn
from the simulator's seed.
Left out (the default), every simulated session is as it was: the link is the motor.
A few arc-seconds (1 arcsec = 4.85e-6 rad) is an industrial arm's.

Unknown keys are errors; every error is a :class:`ConfigError` naming the file
and the key path (``truth.json: parameters.k3: missing required key``).
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from calibration.robots import ROBOTS, get_robot
from drivers.atomic import write_atomic
from drivers.config_reader import KeyReader, frozen_map, load_json
from drivers.sim.repeatability import parse_repeatability, repeatability_dict

NOISE_CHANNELS = ("distance", "tilt", "roll", "pitch", "yaw", "qm", "position", "pose")
PLANE_KEYS = ("plane_a", "plane_b", "plane_c")


@dataclass(frozen=True)
class SimTruth:
    """The true robot behind the simulated devices.

    robot:       ``"agebot-sm"`` or ``"agebot-pm"``.
    parameters:  name -> true value of every model parameter (model order).
    plane:       ``(a, b, c)`` of the sm-plane plane ``a x + b y + c z + 1 = 0`` (1/m), or None.
    noise:       channel -> std of one reading (see module docstring); absent = 0.
    seed:        seed of the noise generator, or None (fresh entropy).
    inclinometer_mount: ``(rx, ry)`` rad, PM inclinometer mounting rotation ``Rx(rx) Ry(ry)``.
    comment:     free text from the file.
    source:      file it was read from (for messages), or None.
    """

    robot: str
    parameters: Mapping[str, float]
    noise: Mapping[str, float] = dataclasses.field(default_factory=lambda: frozen_map({}))
    seed: int | None = None
    plane: tuple[float, float, float] | None = None
    inclinometer_mount: tuple[float, float] = (0.0, 0.0)
    comment: str | None = None
    source: str | None = None
    spec: Any = None  # the robot file's SerialSpec (a URDF robot's true UrdfSpec), or None
    robot_file: str | None = None  # its path as the truth file gives it
    frame: tuple | None = None    # a URDF robot's measurement frame ((x, y, z), (r, p, y))
    points: tuple | None = None   # a URDF robot's points on the tool (M, 3) tip link frame
    #: ``{"backlash": (n,), "positioning": (n,)}`` per joint (rad, m), or None (module doc)
    repeatability: Mapping[str, tuple] | None = None

    def model(self):
        """The robot model (built-in or the robot file's)."""
        return get_robot(self.spec if self.spec is not None else self.robot)

    def xi(self) -> np.ndarray:
        """The true parameter vector ``(N,)`` in the model's order."""
        names = self.model().param_names
        return np.array([self.parameters[n] for n in names], dtype=float)

    def sigma(self, channel: str) -> float:
        """Std of one reading of ``channel`` (0 where the file gives none)."""
        return float(self.noise.get(channel, 0.0))

    def without_noise(self) -> "SimTruth":
        """The same robot with every channel noise-free."""
        return dataclasses.replace(self, noise=frozen_map({}))



def report_truth(robot: str) -> SimTruth:
    """The report's true values for ``robot`` (docs/models.md), noise-free."""
    model = get_robot(robot)
    return SimTruth(robot=robot, parameters=frozen_map(model.as_dict(model.true)))


def parse_truth(data: Any, source: str | None = None) -> SimTruth:
    """Parse a decoded truth JSON object; errors name ``source`` and the key path."""
    top = KeyReader(data, "", source)
    if isinstance(data, dict) and data.get("robot") == "urdf":
        from drivers.sim.urdf_truth import parse_urdf_truth

        return SimTruth(**parse_urdf_truth(top, source))
    spec, file_path = None, None
    if "robot_file" in top.data:
        from drivers.robot_file import load_robot_file

        file_path = top.str("robot_file")
        base = Path(source).parent if source else Path(".")
        spec = load_robot_file(base / file_path)
        robot = top.str("robot")
        if robot != spec.name:
            top.fail("robot", f"{robot!r} is not the robot file's name {spec.name!r}")
        model = get_robot(spec)
    else:
        robot = top.choice("robot", ROBOTS)
        model = get_robot(robot)
    pr = top.table("parameters")
    params = ({n: pr.float(n, default=float(v)) for n, v in zip(model.param_names, model.nominal)}
              if spec is not None else {n: pr.float(n) for n in model.param_names})
    plane = None
    if model.kind == "serial" and any(k in pr.data for k in PLANE_KEYS):
        plane = tuple(pr.float(k) for k in PLANE_KEYS)
        if plane == (0.0, 0.0, 0.0):
            pr.fail("plane_a", "a plane a x + b y + c z + 1 = 0 needs (a, b, c) != 0")
    for k in pr.keys():
        if k not in params and not (plane and k in PLANE_KEYS):
            pr.fail(k, f"unknown parameter for {robot} (known: {', '.join(model.param_names)}"
                    + (", plane_a, plane_b, plane_c)" if model.kind == "serial" else ")"))
    pr.finish()
    noise = {}
    nr = top.table("noise", required=False)
    if nr is not None:
        for ch in nr.keys():
            if ch not in NOISE_CHANNELS:
                nr.fail(ch, f"unknown channel (known: {', '.join(NOISE_CHANNELS)})")
            noise[ch] = (list(nr.float_list(ch, length=6, lo=0.0, scalar_ok=True)) if ch == "pose"
                         else nr.float(ch, lo=0.0))
    seed = top.int("seed", default=None, lo=0)
    mount = (0.0, 0.0)
    if "inclinometer_mount" in top.data:
        if robot != "agebot-pm" and spec is None:
            top.fail("inclinometer_mount", "only the agebot-pm and robot files have an "
                     "inclinometer mount")
        mount = top.float_list("inclinometer_mount", length=2)
        if max(abs(m) for m in mount) > math.pi / 4:
            top.fail("inclinometer_mount", "a mounting rotation is small: |rx|, |ry| <= pi/4")
    repeatability = parse_repeatability(top, model.n_actuators)
    comment = top.str("comment", default=None)
    top.finish()
    return SimTruth(robot=robot, parameters=frozen_map(params), noise=frozen_map(noise),
                    seed=seed, plane=plane, inclinometer_mount=tuple(mount),
                    comment=comment, source=source, spec=spec, robot_file=file_path,
                    repeatability=repeatability)


def load_truth(path: str | Path) -> SimTruth:
    """Read a truth file; errors name the file and the key."""
    return parse_truth(load_json(path), str(path))


def truth_to_dict(truth: SimTruth) -> dict:
    """The JSON object of ``truth`` (inverse of :func:`parse_truth`)."""
    if truth.robot == "urdf":          # its true URDF, the room and the points
        from drivers.sim.urdf_truth import urdf_truth_dict

        out: dict[str, Any] = urdf_truth_dict(truth)
    else:
        params = dict(truth.parameters)
        if truth.plane is not None:
            params.update(zip(PLANE_KEYS, truth.plane))
        out = {"robot": truth.robot, "parameters": params}
        if truth.robot_file is not None:
            out["robot_file"] = truth.robot_file
    if truth.noise:
        out["noise"] = dict(truth.noise)
    if truth.seed is not None:
        out["seed"] = truth.seed
    if (truth.robot == "agebot-pm" or truth.spec is not None) and any(truth.inclinometer_mount):
        out["inclinometer_mount"] = list(truth.inclinometer_mount)
    if truth.repeatability:
        out["repeatability"] = repeatability_dict(truth)
    if truth.comment:
        out["comment"] = truth.comment
    return out


def save_truth(truth: SimTruth, path: str | Path) -> None:
    """Write ``truth`` as JSON atomically (:func:`drivers.atomic.write_atomic`); a URDF
    robot's true URDF first, beside it (its ``robot_file``, relative to ``path``)."""
    if truth.robot == "urdf":
        write_atomic(Path(path).parent / truth.robot_file,
                     truth.spec.source["text"].encode("utf-8"))
    write_atomic(path, (json.dumps(truth_to_dict(truth), indent=2) + "\n").encode("utf-8"))


#: Default spread of :func:`draw_truth`, as users' robots differ from a nominal:
#: gear ratios ``k*`` relative, lengths relative, offsets (``*_off``, ``theta*``) absolute.
DRAW_SPREAD = {"gear": 0.4, "length": 0.05, "offset": 0.03}


def _spread_kind(name: str) -> str:
    if name[0] == "k" and name[1:].isdigit():
        return "gear"
    if name.endswith("_off") or name.startswith(("theta", "alpha", "beta", "gamma")) or name == "off":
        return "offset"
    return "length"


def draw_truth(robot, rng: np.random.Generator, *, gear: float = DRAW_SPREAD["gear"],
               length: float = DRAW_SPREAD["length"], offset: float = DRAW_SPREAD["offset"],
               noise: Mapping[str, float] | None = None, seed: int | None = None,
               inclinometer_mount: tuple[float, float] = (0.0, 0.0),
               comment: str | None = None) -> SimTruth:
    """A robot that is not the report's: every parameter drawn uniformly around the nominal.

    Gear ratios ``k*`` are the nominal times ``1 + U(-gear, gear)``, offsets (``q*_off``,
    ``theta*``) the nominal plus ``U(-offset, offset)``, every other parameter (lengths)
    the nominal times ``1 + U(-length, length)``. ``noise``, ``seed`` and
    ``inclinometer_mount`` pass through to the :class:`SimTruth`.

    The wrist (``agebot-pm``) is the exception for its lengths: the report's nominal
    wrist cannot be built (its rods are too short to reach the platform even at
    ``X = 0``, report section 10), so its lengths ``a1, a2, l, v`` are drawn around
    the report's measured (true) values; gear ratios and offsets still around the
    nominal, which is what a session starts from.

    ``robot`` may also be a robot file's ``SerialSpec``: its angles (``alpha*``,
    ``beta*``, ``theta*``, the base's and tool's ``theta, alpha, gamma``) are drawn as
    offsets, its ``fixed`` parameters stay at the file's values.
    """
    model = get_robot(robot)
    spread = {"gear": gear, "length": length, "offset": offset}
    centre = np.asarray(model.nominal, dtype=float).copy()
    if robot == "agebot-pm":
        centre[:4] = np.asarray(model.true, dtype=float)[:4]
    spec = robot if not isinstance(robot, str) else None
    params = {}
    for name, nom in zip(model.param_names, centre):
        if spec is not None and name in model.fixed:
            params[name] = float(nom)
            continue
        kind = _spread_kind(name.split("_")[-1] if spec is not None else name)
        u = float(rng.uniform(-spread[kind], spread[kind]))
        params[name] = float(nom + u) if kind == "offset" else float(nom * (1.0 + u))
    return SimTruth(robot=model.name, spec=spec, parameters=frozen_map(params),
                    noise=frozen_map(dict(noise or {})), seed=seed,
                    inclinometer_mount=tuple(inclinometer_mount), comment=comment)
