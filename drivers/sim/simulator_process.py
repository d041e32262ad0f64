"""``app.py simulate`` in a child process (:class:`SimulatorProcess`): the simulated
devices in their own process, as at a real station, for the headless run, the wizard,
``devices check --simulate`` and the tests.

The child is started with ``--exit-with-parent`` (it ends when its parent does, even
killed); its first line on stdout is the endpoints JSON (cli.md), which is what
:attr:`SimulatorProcess.endpoints` holds. A simulator that stops before it started its
devices is :class:`SimulatorFailed` with its one-line reason; one that says nothing
within the start timeout a :class:`~drivers.errors.DeviceError`. :meth:`SimulatorProcess.stop`
ends it (SIGTERM, then SIGKILL).
"""
from __future__ import annotations

import json
import sys
import threading
from pathlib import Path

from calibration.errors import StationError
from drivers.config import StationConfig
from drivers.endpoints import with_endpoints
from drivers.sim.control import SimControl
from drivers.sim.station_files import ROOT, load_sim_config


class SimulatorFailed(StationError, RuntimeError):
    """The simulator process stopped before it started its devices (its one-line reason:
    a truth file of another robot, a bad config, ...)."""


class SimulatorProcess:
    """``app.py simulate`` in a child process: the simulated devices in their own
    process, as at a real station. ``endpoints`` is what it printed; :meth:`stop`
    ends it (SIGTERM, then SIGKILL)."""

    def __init__(self, robot: str, truth: str | None = None, config: str | None = None, *,
                 seed: int | None = None, timeout: float = 20.0, pose_noise: bool = False):
        import subprocess

        self.robot, self.config_path = robot, (Path(config) if config else None)
        self.truth = truth
        from drivers.robot_file import robot_args

        cmd = [sys.executable, str(ROOT / "app.py"), "simulate", *robot_args(robot),
               "--exit-with-parent"]
        if truth:
            cmd += ["--truth", str(truth)]
        if config:
            cmd += ["--config", str(config)]
        if seed is not None:
            cmd += ["--seed", str(seed)]
        if pose_noise:
            cmd += ["--pose-noise"]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            self.endpoints = self._first_line(timeout)
        except BaseException:
            self.stop()
            raise
        self.stderr_tail: list[str] = []
        for stream in (self.proc.stdout, self.proc.stderr):
            threading.Thread(target=self._consume, args=(stream,), daemon=True).start()

    def _first_line(self, timeout: float) -> dict:
        import select

        from drivers.errors import DeviceError

        if not select.select([self.proc.stdout], [], [], timeout)[0]:
            raise DeviceError(f"did not start within {timeout:.0f} s", device="simulator")
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read().decode(errors="replace").strip().splitlines()
            last = err[-1] if err else f"code {self.proc.wait()}"
            raise SimulatorFailed("the simulator did not start: " + last.removeprefix("error: "))
        return json.loads(line)

    @property
    def alive(self) -> bool:
        """False once the simulator's process has ended (killed, crashed)."""
        return self.proc.poll() is None

    def _consume(self, stream) -> None:
        try:
            for line in stream:
                if stream is self.proc.stderr:
                    self.stderr_tail = (self.stderr_tail + [line.decode(errors="replace")])[-20:]
        except (OSError, ValueError):
            pass

    def control(self) -> SimControl:
        return SimControl.from_endpoints(self.endpoints)

    def station_config(self) -> StationConfig:
        """The station config it was started with, its endpoints filled from this simulator."""
        return with_endpoints(load_sim_config(self.robot, self.config_path, self.truth),
                              self.endpoints, source="simulator")

    def stop(self) -> None:
        import subprocess

        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
