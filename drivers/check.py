"""``python app.py devices check``: connect to the configured devices, print live readings.

    app.py devices check --config stations/lab.toml
    app.py devices check --config fixtures/stations/sim-sm.toml --endpoints ep.json
    app.py devices check --simulate --robot agebot-pm

Each device is opened on its own, so that one missing cable does not hide the
others; what is wrong is said with what to check. Exit 0 only if every device
answered.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

from calibration.errors import ConfigError, StationError
from drivers.config import load_station_config
from drivers.endpoints import load_endpoints, with_endpoints
from drivers.errors import DeviceError, DeviceTimeout
from drivers.mocap import AXES, MotionCapture
from drivers.rig import Rig

HINTS = {
    "canopen": "check the CAN cable and termination, the bus interface and bitrate in "
               "[canopen], and that every node id in canopen.nodes is powered",
    "inclinometer": "check the serial cable, inclinometer.port and inclinometer.baudrate",
    "draw-wire": "check the Modbus link (drawwire.host/port or serial_port), device_id "
                 "and that the sensor is powered",
    "motion capture": "check that QTM runs with real-time output on mocap.host/port, is "
                      "measuring, and labels the markers as mocap.labels says",
}


#: what to check where the devices are simulated (no cable to check)
SIMULATED_HINT = ("the simulated devices' process stopped or does not answer: connect again "
                  "(the wizard's Connect, or the same command) to start the simulator anew")


def hint_for(device: str, simulated: bool = False) -> str:
    """What to check when ``device`` does not answer (``simulated``: a simulator's)."""
    if simulated:
        return SIMULATED_HINT
    for key, text in HINTS.items():
        if device.startswith(key):
            return text
    return "check the device's cable and its section of the station config"


def reading_text(device, sample) -> str:
    """One device's reading for people: a motion capture's markers by label in mm ("not
    seen" where NaN), any other device's channels."""
    if isinstance(device, MotionCapture):
        out = []
        for k, label in enumerate(device.labels, start=1):
            xyz = [sample.values[f"m{k}_{a}"] * 1e3 for a in AXES]
            out.append(f"{label} not seen" if any(math.isnan(v) for v in xyz)
                       else f"{label} ({xyz[0]:.1f}, {xyz[1]:.1f}, {xyz[2]:.1f}) mm")
        return "; ".join(out)
    return ", ".join(f"{ch} {v:.6g}" for ch, v in sample.values.items())


def _config(args):
    if args.config is None and not args.endpoints:
        raise ConfigError("give --config FILE (the station config), or --simulate to check "
                          "the simulated station")
    from drivers.sim.station_files import default_config_path

    path = args.config
    endpoints = load_endpoints(args.endpoints) if args.endpoints else None
    if path is None:
        path = default_config_path(endpoints.get("robot", args.robot))
    config = load_station_config(path)
    if endpoints is not None:
        config = with_endpoints(config, endpoints, source=args.endpoints)
    return config


def check(config, seconds: float = 3.0, out=None, failed: list | None = None) -> bool:
    """Open each device, print readings for ``seconds`` (to ``out``, default stdout);
    True if all answered (``failed``, a list, gets the names of those that did not)."""
    out = out or sys.stdout
    rig = Rig(config)
    ok: dict[str, str | None] = {}
    for d in rig.devices:
        try:
            d.open()
            ok[d.name] = None
        except (DeviceError, OSError) as e:
            ok[d.name] = str(e)
    if rig.can_move and ok.get(rig.actuators.name) is None:
        try:
            sw = {nid: rig.actuators.statusword(nid) for nid in rig.actuators.nodes}
            from drivers.canopen_drives import state_name

            print("drives: " + ", ".join(f"node {n} {state_name(s)}" for n, s in sw.items()),
                  file=out)
        except DeviceError as e:
            ok[rig.actuators.name] = str(e)
    try:
        end = time.monotonic() + seconds
        while True:
            parts = []
            for d in rig.devices:
                if ok[d.name] is not None:
                    continue
                try:
                    parts.append(reading_text(d, d.read()))
                except (DeviceError, DeviceTimeout) as e:
                    ok[d.name] = str(e)
            print(" | ".join(parts) if parts else "(no device answers)", file=out, flush=True)
            if time.monotonic() >= end:
                break
            time.sleep(min(0.5, max(0.0, end - time.monotonic())))
    finally:
        rig.close()
    print("", file=out)
    for name, err in ok.items():
        if err is None:
            print(f"  OK    {name}", file=out)
        else:
            print(f"  FAIL  {name}: {err}\n        -> {hint_for(name)}", file=out)
    if failed is not None:
        failed.extend(name for name, err in ok.items() if err is not None)
    return all(v is None for v in ok.values())


def main(args: argparse.Namespace) -> int:
    failed: list[str] = []
    if getattr(args, "simulate", False):
        from drivers.sim.server import SimulatorProcess

        from drivers.robot_file import is_robot_file
        from drivers.sim.station_files import truth_of

        truth = getattr(args, "truth", None)
        if is_robot_file(args.robot):       # its truth (a URDF robot needs one): one line
            truth_of(args.robot, truth)
        with SimulatorProcess(args.robot, truth=truth, config=args.config) as sim:
            good = check(sim.station_config(), args.seconds, failed=failed)
    else:
        good = check(_config(args), args.seconds, failed=failed)
    if not good:
        raise StationError(f"{', '.join(failed) or 'some devices'} did not answer (see above)")
    return 0
