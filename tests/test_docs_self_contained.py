"""The documentation is the repository's own (issue 23, finding 13): a clone has no
../shared, so README.md and docs/ never send a reader there."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_readme_and_docs_point_to_nothing_outside_the_repository():
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for outside in ("../shared", "shared/spec", "shared/seed", "calibration-brief.md"):
            assert outside not in text, f"{path.name} points to {outside}"
    for name in ("models.md", "robot-files.md", "report-summary.md"):
        assert (ROOT / "docs" / name).is_file()
