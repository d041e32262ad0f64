"""Next month's recalibration starts from last month's URDF: the station's own export
imports and calibrates as well as the original (docs/urdf-robots.md, "Calibrating
again from the exported URDF"). A calibrated robot's axes are a milliradian off the
nominal's parallels, so the original's exact dependencies become near ones; the
identifiability analysis must keep a well-conditioned set
(:func:`calibration.identifiability.classify`) or the fit crawls along them."""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from tests.station.urdf_helpers import URDF, import_args, tracker_case, turned_wrist
from tests.station.cli_helpers import run

TIAGO = Path(__file__).resolve().parents[3] / "shared" / "data" / "tiago"
TIAGO_IGNORE = "shipped_row,t_start_robot,t_end_robot,marker_std_mm"


def calibrated(capsys, trace: Path, params: Path) -> tuple[dict, str]:
    rc, out, err = run(capsys, "batch", trace, "--out", params)
    assert rc == 0, err
    assert "fit quality: passed" in out, out
    return json.loads(params.read_text()), out


def held_out(doc: dict) -> dict:
    return next(c["points"] for c in doc["fit"]["quality"]["checks"] if "points" in c)


def iterations(out: str) -> int:
    return int(re.search(r"converged in (\d+) iterations", out).group(1))


def assert_same_calibration(first, again, out_again, *, rel: float):
    """The second fit, from the export, converged in few iterations, to the same fit and
    held-out errors, and moved the export's joint origins by less than the first fit's
    std (the export already holds the calibration)."""
    assert iterations(out_again) <= 40, out_again
    assert again["fit_points"]["rms"] == pytest.approx(first["fit_points"]["rms"], rel=rel)
    a, b = held_out(first), held_out(again)
    assert b["rms_after"] == pytest.approx(a["rms_after"], rel=rel)
    assert b["rms_before"] <= a["rms_after"] * (1 + rel)  # the export's start is calibrated
    assert again["fit"]["identifiable_count"] >= 0.9 * first["fit"]["identifiable_count"]


def turned(folder: Path) -> Path:
    """The simulated arm's URDF with joint 5's frame turned as many ROS URDFs turn theirs
    (:func:`tests.station.urdf_helpers.turned_wrist`), written in ``folder``."""
    out = folder / "turned.urdf"
    out.write_text(turned_wrist(URDF.read_text()))
    return out


def test_a_simulated_arm_recalibrates_from_its_exported_urdf(tmp_path, capsys):
    tracker_case(tmp_path, seed=5, noise=5e-4)  # a motion-capture room
    args = import_args(tmp_path)
    args[args.index(str(URDF))] = str(turned(tmp_path))
    rc, out, err = run(capsys, *args)
    assert rc == 0, err
    first, _ = calibrated(capsys, tmp_path / "t.jsonl", tmp_path / "p.json")
    rc, out, err = run(capsys, "params", "export", tmp_path / "p.json", "--urdf",
                       tmp_path / "cal.urdf")
    assert rc == 0, err
    args[args.index(str(tmp_path / "turned.urdf"))] = str(tmp_path / "cal.urdf")
    args[args.index(str(tmp_path / "t.jsonl"))] = str(tmp_path / "t2.jsonl")
    rc, out, err = run(capsys, *args)
    assert rc == 0, err
    again, out = calibrated(capsys, tmp_path / "t2.jsonl", tmp_path / "p2.json")
    assert_same_calibration(first, again, out, rel=0.02)
    # and once more from that one's export: nothing accumulates
    assert run(capsys, "params", "export", tmp_path / "p2.json", "--urdf",
               tmp_path / "cal2.urdf")[0] == 0
    args[args.index(str(tmp_path / "cal.urdf"))] = str(tmp_path / "cal2.urdf")
    args[args.index(str(tmp_path / "t2.jsonl"))] = str(tmp_path / "t3.jsonl")
    assert run(capsys, *args)[0] == 0
    third, out = calibrated(capsys, tmp_path / "t3.jsonl", tmp_path / "p3.json")
    assert_same_calibration(first, third, out, rel=0.02)


def _tiago_data() -> Path:
    if not (TIAGO / "tiago_48_schunk.urdf").is_file():
        if os.environ.get("CI") == "true":
            pytest.fail(f"FIGAROH's TIAGo data are missing at {TIAGO}")
        pytest.skip(f"FIGAROH's TIAGo data are not at {TIAGO} (docs/urdf-robots.md)")
    return TIAGO


@pytest.mark.slow
def test_tiago_joint_offsets_reproduce_figaroh_s_figures(tmp_path, capsys):
    """FIGAROH's TIAGo example as it comes (marker 1, joint offsets only): the fit, the
    held-out and the worst held-out 3D errors to FIGAROH's printed digits, 2.88 / 4.23 /
    12.0 mm (docs/urdf-robots.md, "A worked example: TIAGo")."""
    data = _tiago_data()
    others = ",".join(f"{a}{j}" for j in (2, 3, 4) for a in "xyz")
    rc, _o, err = run(capsys, "trace", "import", data / "qualisys_2021-11-30_static_postures.csv",
                      "--validation", data / "qualisys_2021-11-26_static_postures.csv",
                      "--robot", data / "tiago_48_schunk.urdf", "--base-link", "base_footprint",
                      "--tip-link", "wrist_ft_tool_link", "--method", "sm-markers",
                      "--ignore-columns", f"{TIAGO_IGNORE},{others}", "--out", tmp_path / "t.jsonl")
    assert rc == 0, err
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--hold", "j*", "--out",
                       tmp_path / "p.json")
    assert rc == 0, err
    doc = json.loads((tmp_path / "p.json").read_text())
    pts = held_out(doc)
    figures = (round(doc["fit_points"]["rms"] * 1e3, 2), round(pts["rms_after"] * 1e3, 2),
               round(pts["max_after"] * 1e3, 1))
    assert figures == (2.88, 4.23, 12.0), (figures, out)


@pytest.mark.slow
def test_tiago_recalibrates_from_its_exported_urdf(tmp_path, capsys):
    data = _tiago_data()

    def imported(urdf: Path, out: Path):
        rc, _o, err = run(capsys, "trace", "import",
                          data / "qualisys_2021-11-30_static_postures.csv", "--validation",
                          data / "qualisys_2021-11-26_static_postures.csv", "--robot", urdf,
                          "--base-link", "base_footprint", "--tip-link", "wrist_ft_tool_link",
                          "--method", "sm-markers", "--ignore-columns", TIAGO_IGNORE,
                          "--out", out)
        assert rc == 0, err

    imported(data / "tiago_48_schunk.urdf", tmp_path / "t.jsonl")
    first, _ = calibrated(capsys, tmp_path / "t.jsonl", tmp_path / "p.json")
    assert held_out(first)["rms_after"] * 1e3 == pytest.approx(4.20, abs=0.02)
    rc, _o, err = run(capsys, "params", "export", tmp_path / "p.json", "--urdf",
                      tmp_path / "cal.urdf")
    assert rc == 0, err
    imported(tmp_path / "cal.urdf", tmp_path / "t2.jsonl")
    again, out = calibrated(capsys, tmp_path / "t2.jsonl", tmp_path / "p2.json")
    assert_same_calibration(first, again, out, rel=0.01)
