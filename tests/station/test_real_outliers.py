"""Real data judged right (issue 42): outliers judged per pose by what the pose does to
the fit, at the model-error level real residuals show
(:mod:`station.fitting.pose_outliers`).

The slow tests read ``../shared/data/`` (its README: the project commits none of it;
CI has it beside the clone):

* FANUC R-2000iC/165F, laser tracker, three reflectors (R. A. Boby, A. Klimchik): every
  one of the five ways to hold out every 5th pose passes the default gate as it comes;
  the held-out 3D RMS per fold and its mean; with compliance offered (a tip load for
  the arm's weight), judged by cross-validation over the fit poses, below 0.38 mm;
* TIAGo, FIGAROH's protocol, marker 1, the full geometric model: pose 6, far from the
  prediction of the fit without it but the others predicted no better without it, is
  kept; held-out 3.08 mm (FIGAROH's 3.07); with compliance, supported by
  cross-validation, 2.907 mm.
"""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from calibration import pose_quality as pq
from calibration import quality as q
from tests.station.cli_helpers import run

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
FANUC = DATA / "fanuc"
TIAGO = DATA / "tiago"
TIAGO_IGNORE = "shipped_row,t_start_robot,t_end_robot,marker_std_mm"

#: the controller's J3 is counted from the horizontal: the URDF's joint_3 is J2 + J3
FANUC_MAP = """format = "calstation-joint-map"
version = 1
[[joint]]
urdf = "joint_3"
terms = { J2 = 1.0, J3 = 1.0 }
""" + "".join(f'[[joint]]\nurdf = "joint_{j}"\ncolumn = "J{j}"\n' for j in (1, 2, 4, 5, 6))


def _data(folder: Path, probe: str) -> Path:
    if not (folder / probe).is_file():
        if os.environ.get("CI") == "true":
            pytest.fail(f"the real data are missing at {folder}")
        pytest.skip(f"the real data are not at {folder} (../shared/data/README.md)")
    return folder


def held_out(doc: dict) -> dict:
    return next(c["points"] for c in doc["fit"]["quality"]["checks"] if "points" in c)


def fanuc_fold(folder: Path, fold: int) -> Path:
    """The FANUC poses as a CSV a user writes: J1..J6 (deg), the three reflectors (mm),
    every 5th pose from ``fold`` held out (``use``)."""
    rows = [line.split() for line in
            (FANUC / "N1N2N3Jval.csv").read_text().splitlines() if line.strip()]
    out = folder / f"fanuc-{fold}.csv"
    with out.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"J{j}" for j in range(1, 7)]
                   + [f"m{m}_{a}" for m in (1, 2, 3) for a in "xyz"] + ["use"])
        for i, v in enumerate(rows):
            vals = [float(x) for x in v]
            w.writerow([repr(x) for x in vals[15:21] + vals[:9]]
                       + ["validation" if i % 5 == fold else "fit"])
    return out


@pytest.mark.slow
def test_fanuc_every_fold_passes_the_default_gate(tmp_path, capsys):
    """Every fold passes as it comes (before: fold 0 refused, "more than 2 readings do
    not fit the others"); held-out 0.404, 0.684, 0.402, 0.182, 0.237 mm, mean 0.382
    (issue 42 asks below 0.38: choosing what is calibrated, its item 3)."""
    _data(FANUC, "N1N2N3Jval.csv")
    (tmp_path / "map.toml").write_text(FANUC_MAP)
    held, written, compliant = [], [], 0
    for fold in range(5):
        csv_path = fanuc_fold(tmp_path, fold)
        trace, params = tmp_path / f"t{fold}.jsonl", tmp_path / f"p{fold}.json"
        rc, _o, err = run(capsys, "trace", "import", csv_path, "--robot",
                          FANUC / "r2000ic165f.urdf", "--base-link", "base_link",
                          "--tip-link", "tool0", "--method", "sm-markers", "--length-unit",
                          "mm", "--angle-unit", "deg", "--joint-map", tmp_path / "map.toml",
                          "--out", trace)
        assert rc == 0, err
        rc, out, err = run(capsys, "batch", trace, "--out", params)
        assert rc == 0, (fold, err)
        assert "fit quality: passed" in out, out
        assert "judged at the model-error level the data show" in out, out
        doc = json.loads(params.read_text())
        assert doc["fit"]["quality"]["outlier_mode"] == "exclude"
        held.append(held_out(doc)["rms_after"] * 1e3)
        # compliance offered, judged by cross-validation over the fit poses (item 3):
        # the URDF has no inertials, a tip load stands in for the arm's weight
        rc, out, err = run(capsys, "batch", trace, "--out", params, "--compliance",
                           "--payload", "100,0,0,0")
        assert rc == 0, (fold, err)
        doc = json.loads(params.read_text())
        cmp = doc["model_comparison"]
        assert cmp["cross_validation"]["rms_compliant"] < cmp["cross_validation"]["rms_rigid"]
        written.append(held_out(doc)["rms_after"] * 1e3)
        compliant += bool(cmp["supported"])
    assert max(held) < 0.70, held
    assert sum(held) / len(held) < 0.385, held
    # the written models: compliant where the fit poses, each predicted unseen, say so
    # (folds 0, 3, 4 with p < 0.001; fold 1 p = 0.014, fold 2 p = 0.095)
    assert compliant >= 3 and max(written) < 0.70, written
    assert sum(written) / len(written) < 0.38, written


@pytest.mark.slow
def test_tiago_full_model_keeps_an_influential_pose_that_predicts_the_others(tmp_path,
                                                                            capsys):
    """Before: pose 6 dropped "2.309 mm from its prediction", 11.9 mm off the final
    model, held-out 3.445 mm. Its deleted residual is 11.9 mm, but the fit without it
    predicts the other poses worse: kept, held-out 3.08 mm (FIGAROH's 3.07)."""
    _data(TIAGO, "tiago_48_schunk.urdf")
    others = ",".join(f"{a}{j}" for j in (2, 3, 4) for a in "xyz")
    rc, _o, err = run(capsys, "trace", "import", TIAGO / "qualisys_2021-11-30_static_postures.csv",
                      "--validation", TIAGO / "qualisys_2021-11-26_static_postures.csv",
                      "--robot", TIAGO / "tiago_48_schunk.urdf", "--base-link", "base_footprint",
                      "--tip-link", "wrist_ft_tool_link", "--method", "sm-markers",
                      "--ignore-columns", f"{TIAGO_IGNORE},{others}", "--out", tmp_path / "t.jsonl")
    assert rc == 0, err
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--out", tmp_path / "p.json")
    assert rc == 0, err
    doc = json.loads((tmp_path / "p.json").read_text())
    assert not doc["fit"]["quality"]["outliers"], out
    assert "pose 6" in out and "kept" in out and "predicts the others no better" in out, out
    assert held_out(doc)["rms_after"] * 1e3 < 3.1
    # compliance offered: supported by cross-validation over the 37 fit postures (27
    # better predicted, p = 0.00056), the held-out day below FIGAROH's 3.07 mm
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--out", tmp_path / "c.json",
                       "--compliance")
    assert rc == 0, err
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["model_comparison"]["supported"], out
    assert doc["model_comparison"]["cross_validation"]["p"] < 0.01, out
    assert held_out(doc)["rms_after"] * 1e3 < 3.0, out


def test_deleted_residual_is_the_error_of_the_fit_without_the_pose():
    """For a linear least-squares problem the block formula is exact: ``(I - H_ii)^-1
    r_i`` is the pose's error from the fit made without its rows."""
    rng = np.random.default_rng(4)
    n_pose, k, p = 12, 6, 5
    J = rng.normal(size=(n_pose * k, p))
    y = J @ rng.normal(size=p) + rng.normal(scale=0.1, size=n_pose * k)
    y[3 * k:4 * k] += 2.0                                   # pose 3: a gross reading
    x = np.linalg.lstsq(J, y, rcond=None)[0]
    r = y - J @ x
    w = np.full(len(y), 4.0)
    U = q.hat_basis(J, w, np.ones(p, bool))
    blocks = pq.pose_blocks(r, U, w, np.repeat(np.arange(n_pose), k))
    assert len(blocks) == n_pose
    for b in blocks:
        keep = np.ones(len(y), bool)
        keep[b.rows] = False
        x_without = np.linalg.lstsq(J[keep], y[keep], rcond=None)[0]
        np.testing.assert_allclose(b.deleted, y[b.rows] - J[b.rows] @ x_without, atol=1e-10)
    worst = max(blocks, key=lambda b: b.t)
    assert worst.pose == 3 and worst.t > worst.threshold
    assert all(b.t < b.threshold for b in blocks if b.pose != 3)


def test_the_level_of_noise_alone_spreads_as_noise_and_model_error_wider():
    """:func:`calibration.pose_quality.robust_level`: poses of pure noise spread as noise
    spreads them (about 1); a heavy tail (what a geometric model cannot describe) far
    wider, and its limit is the data's own."""
    rng = np.random.default_rng(7)
    k = 9
    noise = np.sqrt(rng.chisquare(k, size=4000) / k)
    level = pq.robust_level(noise, [k] * len(noise))
    assert level["spread"] == pytest.approx(1.0, abs=0.08)
    heavy = noise * np.exp(rng.normal(scale=0.6, size=len(noise)))
    wide = pq.robust_level(heavy, [k] * len(heavy))
    assert wide["spread"] > 2.0 and wide["limit"] > 2 * level["limit"]
    assert math.isfinite(wide["median"])


def _heavy_tailed(P, rng, scale=3e-4):
    """Readings whose errors are far above the tracker's noise and heavy-tailed per pose,
    as a geometric model's error is on a real arm: each pose's points displaced together,
    by a size drawn log-normal."""
    out = P.copy()
    for i in range(len(P)):
        out[i] += rng.normal(size=3) * scale * math.exp(rng.normal(scale=0.45))
    return out + rng.normal(scale=3e-5, size=P.shape)


@pytest.mark.parametrize("gross", [0.0, 0.02])
def test_at_the_model_error_level_a_sound_fit_passes_and_a_gross_reading_is_left_out(
        tmp_path, capsys, gross):
    """Simulated residuals ten times the tracker's noise, heavy-tailed per pose: judged
    at the level the data show (said in one line), no pose left out and the fit passes;
    a reflector 20 mm off is still left out, its error under the final model printed."""
    from tests.station.urdf_helpers import import_args, tracker_case

    _rob, _x, _qm, P = tracker_case(tmp_path, seed=3, unseen=0.0, noise=0.0)
    bad = _heavy_tailed(P, np.random.default_rng(11))
    bad[9, 1] += gross * np.array([0.6, -0.8, 0.0])
    tracker_case(tmp_path, seed=3, unseen=0.0, readings=bad)
    assert run(capsys, *import_args(tmp_path))[0] == 0
    rc, out, err = run(capsys, "batch", tmp_path / "t.jsonl", "--out", tmp_path / "p.json")
    assert rc == 0, err
    assert "judged at the model-error level the data show" in out, out
    doc = json.loads((tmp_path / "p.json").read_text())
    outliers = doc["fit"]["quality"]["outliers"]
    if not gross:
        assert outliers == [], out
        return
    assert [o["pose"] for o in outliers] == [9], out
    assert outliers[0]["point"] == 2 and outliers[0]["final"] > 0.015, outliers
    line = next(ln for ln in out.splitlines() if ln.startswith("outlier excluded"))
    assert "from the prediction of the fit without it" in line and "off the final model" in line
