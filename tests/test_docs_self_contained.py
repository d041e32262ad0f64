"""The documentation is the repository's own (issue 23, finding 13): a clone has no
../shared, so README.md and docs/ never send a reader there, and neither does a
comment in the station's source or fixtures: every page it names is in the
repository."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: pointers to files a user of the repository does not have
OUTSIDE = ("../shared", "shared/spec", "shared/seed", "calibration-brief.md")
#: a Markdown page named in a text: ``docs/cli.md``, ``file-formats.md``, ``bench/README.md``
PAGE = re.compile(r"[A-Za-z0-9_./-]*\.md\b")


def _pages_that_do_not_exist(text: str, here: Path) -> list[str]:
    """The ``*.md`` names in ``text`` that are neither a path from the repository's root
    or from ``here`` nor a page of docs/."""
    missing = []
    for name in PAGE.findall(text):
        if not any(p.is_file() for p in (ROOT / name, here / name, ROOT / "docs" / name)):
            missing.append(name)
    return missing


def _docs():
    return [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _source():
    """The station's source and fixtures a user reads (tests and benches excepted:
    developers' tools may read public data from ../shared/data)."""
    files = [ROOT / "app.py"]
    for folder in ("calibration", "cli", "drivers", "station", "fixtures"):
        for ext in ("py", "toml", "json", "j2"):
            files += sorted((ROOT / folder).rglob(f"*.{ext}"))
    return files


def test_readme_and_docs_point_to_nothing_outside_the_repository():
    for path in _docs():
        text = path.read_text(encoding="utf-8")
        for outside in OUTSIDE:
            assert outside not in text, f"{path.name} points to {outside}"
    for name in ("models.md", "robot-files.md", "report-summary.md", "real-station.md"):
        assert (ROOT / "docs" / name).is_file()


def test_every_page_the_readme_and_docs_name_exists():
    for path in _docs():
        missing = _pages_that_do_not_exist(path.read_text(encoding="utf-8"), path.parent)
        assert not missing, f"{path.relative_to(ROOT)} names {missing}, not in the repository"


def test_source_and_fixtures_point_to_nothing_outside_the_repository():
    """A comment says where a fact is written down: docs/<page>.md, never
    shared/spec/... (issue: the operator's path to real hardware, item 10)."""
    files = _source()
    assert len(files) > 100 and ROOT / "fixtures" / "stations" / "example-real.toml" in files
    for path in files:
        text = path.read_text(encoding="utf-8", errors="replace")
        where = path.relative_to(ROOT)
        for outside in OUTSIDE:
            assert outside not in text, f"{where} points to {outside}"
        missing = _pages_that_do_not_exist(text, path.parent)
        assert not missing, f"{where} names {missing}, not in the repository"


def test_the_real_station_example_leads_to_its_page():
    """example-real.toml, the README and docs/cli.md all lead to docs/real-station.md."""
    example = (ROOT / "fixtures" / "stations" / "example-real.toml").read_text(encoding="utf-8")
    assert "docs/real-station.md" in example
    for page in (ROOT / "README.md", ROOT / "docs" / "cli.md"):
        assert "real-station.md" in page.read_text(encoding="utf-8"), page.name
    page = (ROOT / "docs" / "real-station.md").read_text(encoding="utf-8")
    assert "fixtures/stations/example-real.toml" in page
