"""A simulated station as ``app.py run --simulate`` and the wizard's "simulate" start it:
its truth file, the simulator's seed and the trace header's record of them, and the values
an engineer measures before a guided-touching session, read from the truth."""
from __future__ import annotations

import shlex

from calibration.errors import ConfigError
from station.planning.request import MUST_KNOW


def simulated_station(robot: str, truth: str | None, sim_seed: int | None):
    """``(truth, seed, record)`` of a simulated station (the headless run's and the
    wizard's): the truth file (a built-in robot's fixture by default; a robot file
    needs one), the simulator's seed (:func:`simulator_seed`) and the trace header's
    ``station`` record of them."""
    from drivers.sim.serial_robot import is_robot_file
    from drivers.sim.station_files import default_truth_path, truth_of

    if is_robot_file(robot) and not truth:
        from drivers.robot_file import split_urdf_ref

        what = ("URDF robot (its true URDF, the motion-capture room, the points on the tool)"
                if split_urdf_ref(robot) else "robot file (what the simulated arm really is)")
        raise ConfigError(f"a simulated {robot} needs --truth: a truth file of the {what}; "
                          f"draw one with: {draw_command(robot)}")
    truth_of(robot, truth)          # of this robot: refused here in one line
    truth = str(truth or default_truth_path(robot))
    seed = simulator_seed(truth, sim_seed)
    return truth, seed, {"simulator": {"truth": truth, "seed": seed, "pose_noise": True}}


def draw_command(robot: str) -> str:
    """The command line that draws a truth file around ``robot`` (``app.py truth draw``)."""
    from drivers.robot_file import robot_args

    return shlex.join(["python", "app.py", "truth", "draw", *robot_args(robot), "--seed", "1",
                       "--out", "truth.json"])


def simulator_seed(truth: str, given: int | None) -> int:
    """The simulator's seed: ``--sim-seed``, else the truth file's, else 0 (a default
    run is always seeded, so that it can be repeated)."""
    if given is not None:
        return int(given)
    from drivers.sim.truth import load_truth

    seed = load_truth(truth).seed
    return int(seed) if seed is not None else 0


def engineer_measurements(robot: str, method: str, truth: str | None, given: dict) -> dict:
    """Simulated station: the values an engineer measures before a guided-touching
    session (:data:`station.planning.request.MUST_KNOW`), read from the simulator's truth file;
    those ``given`` (``--nominal``) are kept."""
    from drivers.sim.station_files import default_truth_path
    from drivers.sim.truth import load_truth

    t = load_truth(truth or default_truth_path(robot))
    values = dict(t.parameters)
    if t.plane is not None:
        values.update(zip(("plane_a", "plane_b", "plane_c"), t.plane))
    missing = [k for k in MUST_KNOW[method] if k not in given and k not in values]
    if missing:
        raise ConfigError(f"{method} needs {', '.join(missing)}: the truth file gives none; "
                          f"give them with --nominal NAME=VALUE", source=t.source)
    return {k: float(values[k]) for k in MUST_KNOW[method] if k not in given}
