"""``app.py doctor`` / ``gui --check``: missing system libraries of the wizard are
named with the apt-get command that installs them, in one line."""
import subprocess
import sys

import station.doctor as doctor
from tests.station.test_cli import app


def test_missing_libraries_named_with_their_packages(monkeypatch):
    monkeypatch.setattr(doctor, "missing_gui_libraries",
                        lambda: ["libxcb-icccm.so.4", "libxkbcommon-x11.so.0", "libEGL.so.1"])
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
    line = doctor.gui_problem()
    assert "\n" not in line
    assert "libxcb-icccm.so.4" in line
    assert line.endswith("sudo apt-get install -y libegl1 libxcb-icccm4 libxkbcommon-x11-0")
    monkeypatch.setenv("QT_QPA_PLATFORM", "offscreen")   # another plugin: not checked
    assert doctor.gui_problem() is None
    monkeypatch.setattr(doctor, "missing_gui_libraries", lambda: [])
    monkeypatch.delenv("QT_QPA_PLATFORM")
    assert doctor.gui_problem() is None


def test_ldd_parsing_on_a_real_binary(tmp_path):
    """``ldd`` of a binary linked to a library that is not there."""
    import shutil

    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None or shutil.which("ldd") is None:
        assert doctor.missing_libraries(sys.executable) == []
        return
    (tmp_path / "a.c").write_text("void nowhere(void); int main(void){nowhere(); return 0;}\n")
    (tmp_path / "n.c").write_text("void nowhere(void){}\n")
    lib = tmp_path / "libnowhere.so.7"
    subprocess.run([cc, "-shared", "-fPIC", "-Wl,-soname,libnowhere.so.7", "-o", str(lib),
                    str(tmp_path / "n.c")], check=True)
    exe = tmp_path / "a.out"
    subprocess.run([cc, "-o", str(exe), str(tmp_path / "a.c"), str(lib)], check=True)
    lib.unlink()
    assert doctor.missing_libraries(exe) == ["libnowhere.so.7"]


def test_every_library_the_plugin_misses_here_has_a_package():
    for lib in doctor.missing_gui_libraries():
        assert lib in doctor.DEBIAN_PACKAGES, lib


def test_doctor_command(tmp_path):
    r = app("doctor")
    assert r.returncode in (0, 1), r.stderr
    lines = r.stdout.strip().splitlines()
    assert all(ln.split()[0] in ("ok", "FAIL", "warn") for ln in lines[:-1])
    assert any("Python package Jinja2" in ln for ln in lines)
    for dist in ("dask", "jsonschema", "yourdfpy"):
        assert any(f"Python package {dist}: " in ln for ln in lines), dist
    assert any("system libraries of the wizard" in ln for ln in lines)
    assert (r.returncode == 0) == lines[-1].startswith("everything")


def test_every_dependency_of_pyproject_is_checked_as_required():
    """doctor checks each package pyproject.toml's ``dependencies`` names (dask,
    jsonschema and yourdfpy among them), and nothing else: every one is required."""
    import re
    import tomllib
    from pathlib import Path

    project = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml")
                            .read_text(encoding="utf-8"))["project"]
    required = {re.split(r"[\[<>=!~; ]", d, maxsplit=1)[0].lower()
                for d in project["dependencies"]}
    required |= {"distributed"}        # dask[distributed]: app.py study's cluster
    checked = {dist.lower() for _, dist in doctor.PYTHON_PACKAGES}
    assert checked == required
    assert {"dask", "distributed", "jsonschema", "yourdfpy"} <= checked
    optional = {name for extra in project.get("optional-dependencies", {}).values()
                for name in (re.split(r"[\[<>=!~; ]", d, maxsplit=1)[0].lower() for d in extra)}
    assert not optional & checked      # test, mutation, bench extras: not the station's


def test_a_missing_package_fails_naming_what_uses_it(monkeypatch, capsys):
    """A required package that does not import is a FAIL line (exit 1) naming the
    command that uses it and how to install it; the others stay ok."""
    real = doctor.importlib.import_module

    def import_module(name, *a, **kw):
        if name in ("yourdfpy", "dask.distributed", "jsonschema"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return real(name, *a, **kw)

    monkeypatch.setattr(doctor.importlib, "import_module", import_module)
    monkeypatch.setattr(doctor, "missing_gui_libraries", lambda: [])
    monkeypatch.setenv("DISPLAY", ":0")
    rows = {what: (ok, detail) for ok, what, detail in doctor.checks()}
    ok, detail = rows["Python package yourdfpy"]
    assert not ok and "used by URDF robots" in detail
    assert detail.endswith("install with: pip install -e .")
    assert not rows["Python package distributed"][0]
    assert "app.py study" in rows["Python package distributed"][1]
    assert "params verify" in rows["Python package jsonschema"][1]
    assert rows["Python package dask"][0] and rows["Python package numpy"][0]
    assert doctor.main() == 1
    lines = capsys.readouterr().out.splitlines()
    assert any(ln.startswith("FAIL Python package yourdfpy: ") for ln in lines)
    assert any(ln.startswith("ok   Python package dask: ") for ln in lines)


def test_readme_lists_the_wizards_system_packages():
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    for pkg in doctor.GUI_PACKAGES:
        assert pkg in readme, pkg
        assert pkg in doctor.DEBIAN_PACKAGES.values()
