"""Simulator endpoints: the addresses a running simulator picked, merged into a station config.

``app.py simulate --endpoints FILE`` writes them as JSON (cli.md); a station
config names them by the placeholder ``"@endpoints"``, which
:func:`with_endpoints` fills. This module builds on :mod:`drivers.config`
(never the reverse).
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

from calibration.errors import ConfigError
from drivers.config import StationConfig
from drivers.config_reader import KeyReader, load_json


def load_endpoints(path: str | Path) -> dict:
    """The endpoints JSON written by ``app.py simulate --endpoints FILE``."""
    data = load_json(path)
    if not isinstance(data, dict):
        raise ConfigError("expected a JSON object", source=str(path))
    return data


def with_endpoints(config: StationConfig, endpoints: Mapping[str, Any],
                   source: str = "endpoints") -> StationConfig:
    """A copy of ``config`` whose device addresses are those of the running simulator.

    ``endpoints`` as in cli.md: ``canopen`` {interface, host, port, channel, nodes},
    ``inclinometer`` {port, baudrate}, ``drawwire`` {host, port, device_id} (TCP) or
    {mode: "rtu", port: "/dev/pts/N", baudrate}, ``mocap`` {host, port}; mode defaults to TCP where a host
    is given, else to the config's. Given values replace the config's
    (placeholder or not); keys this station does not know are ignored.
    """
    top = KeyReader(endpoints, "", source)
    unresolved = set(config.unresolved)
    changes: dict[str, Any] = {}

    def take(r: KeyReader, key: str, value, section: str, **to) -> None:
        name = to.get("field", key)
        if key in r.data:
            changes.setdefault(section, {})[name] = value(key)
            unresolved.discard(f"{section}.{name}")

    r = top.table("canopen", required=False)
    if r is not None:
        for k in ("interface", "channel", "host"):
            take(r, k, r.str, "canopen")
        take(r, "port", lambda k: r.int(k, lo=1, hi=65535), "canopen")
        n = len(config.canopen.nodes)
        take(r, "nodes", lambda k: r.int_list(k, length=n, lo=1, hi=127), "canopen")
    r = top.table("inclinometer", required=False)
    if r is not None and config.inclinometer is not None:
        take(r, "port", r.str, "inclinometer")
        take(r, "baudrate", lambda k: r.int(k, lo=1), "inclinometer")
    r = top.table("drawwire", required=False)
    if r is not None and config.drawwire is not None:
        guess = "tcp" if "host" in r.data else config.drawwire.mode
        if r.choice("mode", ("tcp", "rtu"), default=guess) == "rtu":
            changes["drawwire"] = {"mode": "rtu", "host": None, "port": None}
            unresolved -= {"drawwire.host", "drawwire.port"}
            take(r, "port", r.str, "drawwire", field="serial_port")
            take(r, "baudrate", lambda k: r.int(k, lo=1), "drawwire")
        else:
            changes["drawwire"] = {"mode": "tcp", "serial_port": None}
            unresolved.discard("drawwire.serial_port")
            take(r, "host", r.str, "drawwire")
            take(r, "port", lambda k: r.int(k, lo=1, hi=65535), "drawwire")
        take(r, "device_id", lambda k: r.int(k, lo=0, hi=247), "drawwire")
    r = top.table("mocap", required=False)
    if r is not None and getattr(config, "mocap", None) is not None:
        take(r, "host", r.str, "mocap")
        take(r, "port", lambda k: r.int(k, lo=1, hi=65535), "mocap")
    sections = {k: dataclasses.replace(getattr(config, k), **v) for k, v in changes.items()}
    dw = sections.get("drawwire")
    for key in (("host", "port") if dw and dw.mode == "tcp" else ("serial_port",) if dw else ()):
        if getattr(dw, key) is None and f"drawwire.{key}" not in unresolved:
            raise ConfigError("missing required key (the drawwire mode changed)",
                              source=source, key=f"drawwire.{'port' if key == 'serial_port' else key}")
    return dataclasses.replace(config, **sections,
                               unresolved=tuple(k for k in config.unresolved if k in unresolved))
