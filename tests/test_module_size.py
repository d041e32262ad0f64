"""No module of the project over :data:`MAX_LINES` lines, in any package (calibration/,
drivers/, station/, cli/) or app.py: a module a reader takes in whole (the house style's
100-300, docs/architecture.md). A module that must be longer goes in :data:`ALLOWED`
with the reason."""
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("calibration", "drivers", "station", "cli")
MAX_LINES = 400

#: path -> why it may be longer (keep this short)
ALLOWED: dict[str, str] = {}


def modules():
    yield ROOT / "app.py"
    for package in PACKAGES:
        yield from sorted((ROOT / package).rglob("*.py"))


def test_every_module_is_short():
    long = {}
    for path in modules():
        rel = path.relative_to(ROOT).as_posix()
        n = len(path.read_text(encoding="utf-8").splitlines())
        if n > MAX_LINES and rel not in ALLOWED:
            long[rel] = n
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_the_allow_list_names_modules_that_need_it():
    for rel, why in ALLOWED.items():
        path = ROOT / rel
        assert path.is_file(), f"{rel}: no such module (remove it from ALLOWED)"
        assert len(path.read_text(encoding="utf-8").splitlines()) > MAX_LINES, \
            f"{rel} is short now: remove it from ALLOWED"
        assert why.strip(), f"{rel}: give the reason"
