"""What the CSV imports share (``app.py trace import``: :mod:`station.recording.trace_import`
for a robot file, :mod:`station.recording.import_markers` for a URDF robot): reading the
file with errors that name it, the length and angle units, and ``--sigma``."""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from calibration.errors import ConfigError

LENGTH = {"m": 1.0, "mm": 1e-3}
ANGLE = {"rad": 1.0, "deg": math.pi / 180}


def open_csv(src: str):
    """``(raw bytes, header cells, row reader)`` of a CSV file; its errors name the file."""
    try:
        raw = Path(src).read_bytes()
        text = raw.decode("utf-8-sig")
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=src) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text: {e}", source=src) from None
    rows = csv.reader(io.StringIO(text))
    try:
        head = [c.strip() for c in next(rows)]
    except StopIteration:
        raise ConfigError("empty file: the first line must name the columns", source=src) from None
    except csv.Error as e:
        raise ConfigError(f"not a CSV file: {e}", source=f"{src}:1") from None
    return raw, head, rows


def parse_sigma(items, channels) -> dict | None:
    """``--sigma CHANNEL=STD`` items as ``{channel: std}`` (SI); the channel must be one
    of ``channels`` and the std a positive finite number."""
    sigma = {}
    for item in items or ():
        k, sep, v = item.partition("=")
        k = k.strip()
        if not sep or k not in channels:
            raise ConfigError(f"--sigma {item}: give CHANNEL=STD with CHANNEL one of "
                              f"{', '.join(channels)}")
        try:
            x = float(v)
        except ValueError:
            raise ConfigError(f"--sigma {item}: {v!r} is not a number (CHANNEL=STD, SI units)") \
                from None
        if not (math.isfinite(x) and x > 0):
            raise ConfigError(f"--sigma {item}: the std must be a positive number")
        sigma[k] = x
    return sigma or None
