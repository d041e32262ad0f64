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


#: the separators a header line may use (the first of these it holds; a comma first:
#: a spreadsheet's ``;`` or tab export is read as it comes)
SEPARATORS = (",", ";", "\t")


def open_csv(src: str):
    """``(raw bytes, header cells, row reader)`` of a CSV file; its errors name the file.
    The separator is the header line's (comma, semicolon or tab); unnamed columns at
    the end of the header (a separator ending every line) are left out where their cells
    are empty, and an unnamed column elsewhere is an error naming it."""
    try:
        raw = Path(src).read_bytes()
        text = raw.decode("utf-8-sig")
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", source=src) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text: {e}", source=src) from None
    first = text.split("\n", 1)[0]
    sep = next((c for c in SEPARATORS if c in first), ",")
    rows = csv.reader(io.StringIO(text), delimiter=sep)
    try:
        head = [c.strip() for c in next(rows)]
    except StopIteration:
        raise ConfigError("empty file: the first line must name the columns", source=src) from None
    except csv.Error as e:
        raise ConfigError(f"not a CSV file: {e}", source=f"{src}:1") from None
    n = len(head)
    while n > 1 and not head[n - 1]:
        n -= 1
    unnamed = [k for k, c in enumerate(head[:n], start=1) if not c]
    if unnamed:
        raise ConfigError(f"column {unnamed[0]} has no name in the header line: name it, or "
                          "remove it", source=f"{src}:1")
    return raw, head[:n], _within(rows, n, src)


def _within(rows, n: int, src: str):
    """The rows cut to the ``n`` named columns; a value in an unnamed one is an error."""
    for lineno, row in enumerate(rows, start=2):
        if any(v.strip() for v in row[n:]):
            raise ConfigError(f"a value beyond the {n} columns the header names (column "
                              f"{n + 1 + next(k for k, v in enumerate(row[n:]) if v.strip())})",
                              source=f"{src}:{lineno}")
        yield row[:n]


def not_a_number(v: str) -> str:
    """Why a cell is not a number, in words: a decimal comma is named."""
    comma = "," in v and v.replace(",", "", 1).replace(".", "", 1).lstrip("+-").isdigit()
    return f"{v[:40]!r} is not a number" + (" (a decimal comma? write it with a point)"
                                           if comma else "")


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
