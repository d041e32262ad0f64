"""The package's layering (house rules): drivers never import station, the
station config does not import the endpoints merge built on it, and every
atomic file write goes through the one writer, drivers.atomic.write_atomic."""
import ast
import os
import stat
from pathlib import Path

import pytest

from drivers.atomic import write_atomic

ROOT = Path(__file__).resolve().parents[2]


def _imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
    return out


def _sources(*folders):
    for folder in folders:
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_drivers_never_import_station():
    bad = {str(p.relative_to(ROOT)): m for p in _sources("drivers") for m in _imports(p)
           if m == "station" or m.startswith("station.")}
    assert not bad


def test_calibration_imports_neither_drivers_nor_station():
    bad = {str(p.relative_to(ROOT)): m for p in _sources("calibration") for m in _imports(p)
           if m.split(".")[0] in ("drivers", "station")}
    assert not bad


def test_config_does_not_import_endpoints():
    assert not any(m.startswith("drivers.endpoints")
                   for m in _imports(ROOT / "drivers" / "config.py"))


def test_one_atomic_writer():
    """No module but drivers/atomic.py renames files into place itself."""
    users = []
    for p in [*_sources("drivers", "station", "calibration", "cli"), ROOT / "app.py"]:
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if (isinstance(node, ast.Attribute) and node.attr in ("replace", "rename")
                    and isinstance(node.value, ast.Name) and node.value.id == "os"):
                users.append(str(p.relative_to(ROOT)))
    assert users == [os.path.join("drivers", "atomic.py")]


def test_write_atomic_replaces_whole_and_cleans_up(tmp_path):
    target = tmp_path / "f.json"
    target.write_bytes(b"old")
    write_atomic(target, b"new content\n")
    assert target.read_bytes() == b"new content\n"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask
    with pytest.raises(TypeError):
        write_atomic(target, object())  # fails while writing: the old file stays
    assert target.read_bytes() == b"new content\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.json"]
