"""``python app.py doctor`` (and ``python app.py gui --check``): what this machine
lacks to run the station, named with the command that installs it.

The wizard needs, besides the Python packages, the system libraries of Qt's
platform plugin: on Linux under X11 the xcb plugin (``libqxcb.so``), whose
dependencies (``libxcb-icccm4``, ``libxkbcommon-x11-0``, ``libEGL``...) a fresh
Debian/Ubuntu install often lacks. Qt then aborts the process (rc 134) with a
message naming another library; :func:`missing_gui_libraries` runs ``ldd`` on the
plugin instead and maps each missing library to its Debian package, so that the
wizard can refuse in one line (:func:`gui_problem`) and ``doctor`` can print the
``apt-get install`` command.
"""
from __future__ import annotations

import importlib
import importlib.metadata
import os
import shutil
import subprocess
import sys
from pathlib import Path

# shared library (soname) -> Debian/Ubuntu package
DEBIAN_PACKAGES = {
    "libxcb.so.1": "libxcb1", "libX11-xcb.so.1": "libx11-xcb1", "libX11.so.6": "libx11-6",
    "libxcb-cursor.so.0": "libxcb-cursor0", "libxcb-icccm.so.4": "libxcb-icccm4",
    "libxcb-image.so.0": "libxcb-image0", "libxcb-keysyms.so.1": "libxcb-keysyms1",
    "libxcb-randr.so.0": "libxcb-randr0", "libxcb-render-util.so.0": "libxcb-render-util0",
    "libxcb-render.so.0": "libxcb-render0", "libxcb-shape.so.0": "libxcb-shape0",
    "libxcb-shm.so.0": "libxcb-shm0", "libxcb-sync.so.1": "libxcb-sync1",
    "libxcb-util.so.1": "libxcb-util1", "libxcb-xfixes.so.0": "libxcb-xfixes0",
    "libxcb-xkb.so.1": "libxcb-xkb1", "libxcb-xinerama.so.0": "libxcb-xinerama0",
    "libxcb-xinput.so.0": "libxcb-xinput0", "libxkbcommon-x11.so.0": "libxkbcommon-x11-0",
    "libxkbcommon.so.0": "libxkbcommon0", "libEGL.so.1": "libegl1", "libGL.so.1": "libgl1",
    "libGLX.so.0": "libglx0", "libGLdispatch.so.0": "libglvnd0", "libOpenGL.so.0": "libopengl0",
    "libfontconfig.so.1": "libfontconfig1", "libfreetype.so.6": "libfreetype6",
    "libdbus-1.so.3": "libdbus-1-3", "libglib-2.0.so.0": "libglib2.0-0",
    "libgthread-2.0.so.0": "libglib2.0-0", "libXau.so.6": "libxau6",
    "libXdmcp.so.6": "libxdmcp6", "libpng16.so.16": "libpng16-16", "libz.so.1": "zlib1g",
    "libSM.so.6": "libsm6", "libICE.so.6": "libice6", "libXrender.so.1": "libxrender1",
}
# what the README lists: the xcb plugin's libraries a minimal system lacks
GUI_PACKAGES = ("libegl1", "libgl1", "libfontconfig1", "libdbus-1-3", "libxkbcommon0",
                "libxkbcommon-x11-0", "libxcb-cursor0", "libxcb-icccm4", "libxcb-image0",
                "libxcb-keysyms1", "libxcb-randr0", "libxcb-render-util0", "libxcb-shape0",
                "libxcb-xkb1")
#: (module, distribution) of every package in pyproject.toml's ``dependencies`` (all
#: required: tests/station/test_doctor.py checks that the two lists agree)
PYTHON_PACKAGES = (("numpy", "numpy"), ("scipy", "scipy"), ("can", "python-can"),
                   ("canopen", "canopen"), ("serial", "pyserial"), ("pymodbus", "pymodbus"),
                   ("matplotlib", "matplotlib"), ("jinja2", "Jinja2"),
                   ("PySide6", "PySide6-Essentials"), ("dask", "dask"),
                   ("dask.distributed", "distributed"), ("jsonschema", "jsonschema"),
                   ("yourdfpy", "yourdfpy"), ("qtm_rt", "qtm-rt"))
#: what uses a package that only some commands need (said where it is missing)
USED_BY = {"dask": "app.py study", "distributed": "app.py study (dask[distributed])",
           "jsonschema": "reading parameter files (params verify, params export)",
           "yourdfpy": "URDF robots (--robot FILE.urdf)",
           "qtm-rt": "the motion capture ([mocap]: Qualisys QTM's real-time protocol)"}


def xcb_plugin() -> Path | None:
    """Qt's xcb platform plugin of the installed PySide6 (None: not found)."""
    try:
        spec = importlib.util.find_spec("PySide6")
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    base = Path(spec.origin).parent
    for p in (base / "Qt" / "plugins" / "platforms" / "libqxcb.so",
              base / "plugins" / "platforms" / "libqxcb.so"):
        if p.is_file():
            return p
    return None


def missing_libraries(binary: Path) -> list[str]:
    """Shared libraries ``ldd`` cannot find for ``binary`` (in its order, once each)."""
    ldd = shutil.which("ldd")
    if ldd is None:
        return []
    try:
        out = subprocess.run([ldd, str(binary)], capture_output=True, text=True,
                             timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    missing = []
    for line in out.splitlines():
        if "not found" in line:
            name = line.split("=>")[0].strip()
            if name and name not in missing:
                missing.append(name)
    return missing


def missing_gui_libraries() -> list[str]:
    """What the xcb plugin lacks on this machine ([] elsewhere than Linux)."""
    if not sys.platform.startswith("linux"):
        return []
    plugin = xcb_plugin()
    return missing_libraries(plugin) if plugin is not None else []


def apt_command(libraries) -> str:
    """The command that installs the packages of ``libraries``."""
    packages = sorted({DEBIAN_PACKAGES.get(lib, lib) for lib in libraries})
    return "sudo apt-get install -y " + " ".join(packages)


def gui_problem() -> str | None:
    """One line saying why the wizard cannot open its window here, or None. Only the
    X11 platform (xcb) is checked: other platforms (offscreen, wayland) load other
    plugins."""
    platform = os.environ.get("QT_QPA_PLATFORM", "")
    if platform and not platform.startswith("xcb"):
        return None
    missing = missing_gui_libraries()
    if not missing:
        return None
    unknown = [lib for lib in missing if lib not in DEBIAN_PACKAGES]
    return (f"the wizard cannot open a window: Qt's X11 plugin needs {', '.join(missing)} "
            f"(not installed); install with: {apt_command(missing)}"
            + (" (apt-file search <library> names the package of "
               + ", ".join(unknown) + ")" if unknown else ""))


def checks() -> list[tuple[bool, str, str]]:
    """``(ok, what, detail or how to fix)`` for every requirement."""
    out = [(sys.version_info >= (3, 11), "Python >= 3.11", sys.version.split()[0])]
    for module, dist in PYTHON_PACKAGES:
        try:
            importlib.import_module(module)
            version = importlib.metadata.version(dist)
            out.append((True, f"Python package {dist}", version))
        except Exception as e:  # noqa: BLE001 - a broken install is what this reports
            used = f"used by {USED_BY[dist]}; " if dist in USED_BY else ""
            out.append((False, f"Python package {dist}",
                        f"{type(e).__name__}: {e}; {used}install with: pip install -e ."))
    try:
        from station.outputs.report import template_environment

        template_environment().get_template("report.html.j2")
        out.append((True, "report template", "station/templates/report.html.j2"))
    except Exception as e:  # noqa: BLE001
        out.append((False, "report template", f"{e}; reinstall with: pip install -e ."))
    if sys.platform.startswith("linux"):
        plugin = xcb_plugin()
        missing = missing_gui_libraries()
        if plugin is None:
            out.append((False, "Qt X11 plugin (libqxcb.so)", "not found in PySide6"))
        elif missing:
            out.append((False, "system libraries of the wizard (Qt xcb)",
                        f"missing {', '.join(missing)}; install with: {apt_command(missing)}"))
        else:
            out.append((True, "system libraries of the wizard (Qt xcb)", "all found"))
        display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
        out.append((bool(display), "a display for the wizard",
                    display or "DISPLAY and WAYLAND_DISPLAY are unset: the wizard needs a "
                               "desktop session; headless use 'python app.py run'"))
    return out


def main(args=None) -> int:
    """Print every check; exit 1 when something the station needs is missing (the
    display only warns: the headless commands do not need it)."""
    bad = 0
    for ok, what, detail in checks():
        required = what != "a display for the wizard"
        mark = "ok  " if ok else ("FAIL" if required else "warn")
        print(f"{mark} {what}: {detail}")
        bad += (not ok) and required
    print("everything the station needs is here" if not bad else
          f"{bad} problem(s): see the lines marked FAIL")
    return 1 if bad else 0
