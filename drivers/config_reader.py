"""Typed reading of configuration documents (TOML tables, JSON objects).

:class:`KeyReader` reads one table key by key with type and range checks; every
error is a :class:`ConfigError` naming the file and the key path, e.g.
``stations/sim.toml: drawwire.port: expected an integer``; unknown keys are
errors, missing required keys are named. Used by the station config
(:mod:`drivers.config` and its sections), the endpoints merge (:mod:`drivers.endpoints`)
and the simulator's truth files (:mod:`drivers.sim.truth`); the bounds on the durations
a station config may set (:data:`MAX_TIMEOUT_S`, ...) are here for every section.
"""
from __future__ import annotations

import json
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from calibration.errors import ConfigError

PLACEHOLDER = "@endpoints"
_REQUIRED = object()
#: the longest timeout of one request or read, one motion, and one period (s) a station
#: config sets: a longer one is a typing slip that would hang a command as good as for ever
MAX_TIMEOUT_S = 60.0
MAX_MOVE_S = 3600.0
MAX_PERIOD_S = 10.0


def frozen_map(d: Mapping) -> Mapping:
    """A read-only copy of ``d``."""
    return MappingProxyType(dict(d))


class KeyReader:
    """Typed access to one table of a config document, naming ``source`` and the key path.

    Each getter marks its key as used; :meth:`finish` rejects the keys nobody used.
    ``placeholder`` (a list) allows the value ``"@endpoints"``: the key path is
    appended to the list and None returned.
    """

    def __init__(self, data: Any, path: str, source: str | None, *, indexed: bool = False):
        self.path, self.source, self._indexed = path, source, indexed
        if not isinstance(data, Mapping):
            raise ConfigError(f"expected a table, got {type(data).__name__}",
                              source=source, key=path or None)
        self.data, self._used = data, set()

    def key(self, key) -> str:
        """The key path of ``key`` in this table (``drawwire.port``, ``canopen.nodes[2]``)."""
        if self._indexed:
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else str(key)

    def fail(self, key: str, message: str):
        raise ConfigError(message, source=self.source, key=self.key(key))

    def keys(self) -> list[str]:
        return list(self.data)

    def _get(self, key, default, placeholder):
        self._used.add(key)
        if key not in self.data:
            if default is _REQUIRED:
                self.fail(key, "missing required key")
            return default, True
        v = self.data[key]
        if placeholder is not None and v == PLACEHOLDER:
            placeholder.append(self.key(key))
            return None, True
        return v, False

    def _range(self, key, v, lo, hi, lo_open):
        if lo is not None and (v <= lo if lo_open else v < lo):
            self.fail(key, f"{v!r} must be {'>' if lo_open else '>='} {lo}")
        if hi is not None and v > hi:
            self.fail(key, f"{v!r} must be <= {hi}")
        return v

    def str(self, key, default=_REQUIRED, placeholder=None):
        v, done = self._get(key, default, placeholder)
        if not done and (not isinstance(v, str) or not v):
            self.fail(key, f"expected a non-empty string, got {v!r}")
        return v

    def int(self, key, default=_REQUIRED, lo=None, hi=None, placeholder=None):
        v, done = self._get(key, default, placeholder)
        if done:
            return v
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(key, f"expected an integer, got {v!r}")
        return self._range(key, v, lo, hi, False)

    def float(self, key, default=_REQUIRED, lo=None, hi=None, lo_open=False):
        v, done = self._get(key, default, None)
        if done:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)) or v != v or abs(v) == float("inf"):
            self.fail(key, f"expected a finite number, got {v!r}")
        return self._range(key, float(v), lo, hi, lo_open)

    def choice(self, key, options, default=_REQUIRED):
        v, done = self._get(key, default, None)
        if not done and (isinstance(v, bool) or v not in options):
            self.fail(key, f"{v!r} is not one of {', '.join(map(repr, options))}")
        return v

    def _list(self, key, length, default, scalar_ok, one):
        v, done = self._get(key, default, None)
        if done:
            return tuple(v) if v is not None else v
        if scalar_ok and not isinstance(v, list):
            v = [v] * length
        if not isinstance(v, list) or (length is not None and len(v) != length):
            self.fail(key, f"expected a list of {length or 'some'} values, got {v!r}")
        sub = KeyReader(dict(enumerate(v)), self.key(key), self.source, indexed=True)
        return tuple(one(sub, i) for i in range(len(v)))

    def int_list(self, key, length=None, lo=None, hi=None, default=_REQUIRED):
        return self._list(key, length, default, False, lambda s, i: s.int(i, lo=lo, hi=hi))

    def float_list(self, key, length=None, lo=None, lo_open=False, default=_REQUIRED,
                   scalar_ok=False):
        return self._list(key, length, default, scalar_ok,
                          lambda s, i: s.float(i, lo=lo, lo_open=lo_open))

    def table(self, key, required=True) -> "KeyReader | None":
        v, done = self._get(key, _REQUIRED if required else None, None)
        return None if done else KeyReader(v, self.key(key), self.source)

    def rest(self) -> dict:
        """Every key not read yet (and mark them read)."""
        out = {k: v for k, v in self.data.items() if k not in self._used}
        self._used.update(out)
        return out

    def finish(self) -> None:
        """ConfigError naming the first key that no getter asked for."""
        for k in self.data:
            if k not in self._used:
                self.fail(k, "unknown key")


def decode_text(raw: bytes, source: str) -> str:
    """A config file's text: UTF-8 (with or without a BOM), else a one-line ConfigError
    that says which encoding it looks like (an editor that saved UTF-16)."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\x00" in raw[:200]:
        raise ConfigError("UTF-16 text (or not text at all): save the file as UTF-8",
                          source=source)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}): "
                          "save the file as UTF-8", source=source) from None


def read_text_file(path, what: str) -> str:
    """The text of the file ``path`` (UTF-8, with or without a BOM; :func:`decode_text`),
    else a one-line ConfigError naming the file and ``what`` it is ("the URDF")."""
    path = str(path)
    try:
        raw = Path(path).read_bytes()
    except OSError as e:
        raise ConfigError(f"cannot read {what}: {e.strerror or e}", source=path) from None
    return decode_text(raw, path)


def parse_toml(text: str, source: str | None) -> dict:
    """A TOML document (a leading BOM is taken as the UTF-8 mark it is); a one-line
    ConfigError naming ``source`` for invalid TOML or nesting too deep to read."""
    import tomllib

    try:
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"not valid TOML: {_one_line(e)}", source=source) from None
    except RecursionError:
        raise ConfigError("not valid TOML here: arrays or tables nested too deeply",
                          source=source) from None


def _one_line(e) -> str:
    return " ".join(str(e).split())


def load_json(path: str | Path):
    """A JSON file's content; unreadable or invalid files are ConfigErrors naming the file."""
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=str(path)) from e
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text ({e.reason} at byte {e.start}): save it as UTF-8",
                          source=str(path)) from None
    except json.JSONDecodeError as e:
        raise ConfigError(f"not valid JSON: {e}", source=str(path)) from e
    except RecursionError:
        raise ConfigError("the JSON is nested too deeply", source=str(path)) from None
