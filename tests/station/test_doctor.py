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
    assert any("system libraries of the wizard" in ln for ln in lines)
    assert (r.returncode == 0) == lines[-1].startswith("everything")


def test_readme_lists_the_wizards_system_packages():
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    for pkg in doctor.GUI_PACKAGES:
        assert pkg in readme, pkg
        assert pkg in doctor.DEBIAN_PACKAGES.values()
