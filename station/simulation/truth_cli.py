"""``python app.py truth draw --robot R --seed N --out FILE``: a simulated robot that
is not the nominal, for ``run --simulate``, ``simulate`` and the wizard's ``--truth``.

The robot (a built-in name or a robot file) is drawn around its nominal as the
study and the session benchmark draw theirs (:func:`station.simulation.sessions.station_truth`:
gear ratios within ``+-gear`` relative, lengths within ``+-length`` relative, offsets
and angles within ``+-offset`` rad; a robot file's ``fixed`` parameters held), with
the station's devices' noise and, for a robot file, its tool inclinometer mounted a
little off square. The simulator's noise is seeded by ``seed`` too, so a session on
the file is repeatable. The wizard's "Draw one" writes the same file; the command's
parser and its printout are :mod:`cli.truth`.
"""
from __future__ import annotations

import math
from pathlib import Path

from calibration.errors import ConfigError


def draw_truth_file(robot: str, out, seed: int, *, gear: float | None = None,
                    length: float | None = None, offset: float | None = None,
                    repeatability: str | None = None) -> Path:
    """Draw ``robot`` (seed ``seed``; spreads as the study's, None: its defaults) and
    write the truth file ``out`` atomically; returns its path. ``repeatability``:
    ``"BACKLASH,POSITIONING"`` (rad, every joint) for the truth's ``repeatability``
    (:mod:`drivers.sim.repeatability`; None: none, the drives position exactly)."""
    from drivers.sim.serial_robot import is_robot_file
    from drivers.sim.truth import DRAW_SPREAD, save_truth
    from station.simulation.sessions import station_truth

    given = {"gear": gear, "length": length, "offset": offset}
    for name, v in given.items():
        if v is not None and not (math.isfinite(v) and 0 <= v < (1 if name != "offset"
                                                                  else math.inf)):
            raise ConfigError(f"--{name} {v:g}: expected a spread >= 0"
                              + (" and < 1 (relative)" if name != "offset" else " (rad)"))
    from drivers.robot_file import split_urdf_ref

    if split_urdf_ref(robot) is not None:        # a URDF robot: its own kind of draw
        if any(v is not None for v in given.values()):
            raise ConfigError("--gear, --length and --offset are a robot file's spreads; a "
                              "URDF robot's joint origins are drawn by millimetres and "
                              "milliradians, its joint zeros by milliradians")
        from drivers.sim.truth import save_truth
        from station.simulation.urdf_sessions import truth_beside, urdf_truth

        out = Path(out)
        truth, _x = urdf_truth(robot, int(seed), f"drawn by app.py truth draw, seed {seed}")
        out.parent.mkdir(parents=True, exist_ok=True)
        save_truth(_with_play(truth_beside(truth, out), repeatability), out)
        return out
    if is_robot_file(robot):
        from drivers.robot_file import load_robot_file

        load_robot_file(robot)          # a robot file that cannot be read: said in one line
    elif robot not in ("agebot-sm", "agebot-pm"):
        raise ConfigError(f"--robot {robot}: not a robot (agebot-sm, agebot-pm or a robot "
                          "file, TOML)")
    draw = {k: (DRAW_SPREAD[k] if v is None else float(v)) for k, v in given.items()}
    truth = station_truth(robot, int(seed), **draw)
    out = Path(out)
    if out.parent and not out.parent.is_dir():
        out.parent.mkdir(parents=True, exist_ok=True)
    save_truth(_with_play(truth, repeatability), out)
    return out


def _with_play(truth, text: str | None):
    """``truth`` with ``--repeatability BACKLASH,POSITIONING`` (rad) for every joint."""
    if not text:
        return truth
    import dataclasses

    from drivers.config_reader import frozen_map
    from drivers.sim.repeatability import MAX_PLAY

    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 2 or not all(math.isfinite(t) and 0 <= t <= MAX_PLAY for t in v):
        raise ConfigError(f"--repeatability {text[:40]}: give BACKLASH,POSITIONING in rad, "
                          f"each 0 to {MAX_PLAY:g} (a few arc-seconds: 2e-5,1e-5)")
    n = truth.model().n_actuators
    return dataclasses.replace(truth, repeatability=frozen_map(
        {"backlash": (v[0],) * n, "positioning": (v[1],) * n}))
