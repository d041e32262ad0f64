"""Joint compliance under gravity, offered by ``batch --compliance`` and kept only
where the data support it (issue 26): a drawn compliant arm is recovered within its
std and its geometry is no longer biased; a rigid arm's calibration is unchanged."""
from __future__ import annotations

import json

import numpy as np

import app as app_module
from calibration.robots import get_robot
from drivers.urdf_file import parse_urdf
from station.simulation import tracegen_urdf as tg
from station.fitting.batch import calibrate_trace
from station.recording.import_markers import import_markers
from station.recording.trace_writer import write_trace
from tests.station.urdf_helpers import URDF, arm


def compliant_arm():
    return get_robot(parse_urdf(URDF.read_text(), str(URDF), "base_link", "tool0",
                                compliance=True))


def export_and_import(tmp, rob, seed, **options):
    x, _qm, _P = tg.tracker_export(tmp, rob, seed, **options)
    got = import_markers(tmp / "meas.csv", URDF, base_link="base_link", tip_link="tool0",
                         length_unit="mm", angle_unit="deg", joint_map=tmp / "map.toml")
    write_trace(tmp / "t.jsonl", got.header, None, got.poses)
    return x


def test_drawn_compliant_arms_are_recovered_within_their_std(tmp_path):
    """Ten arms whose joints bend ~2 mrad at their largest gravity load: the compliances
    are supported by the held-out poses and recovered with the geometry within the
    reported std (RMS error/std 0.8-1.3); the rigid fit of the same data is biased."""
    rob = compliant_arm()
    z_all, z_rigid = [], []
    for seed in range(7300, 7310):
        x = export_and_import(tmp_path, rob, seed)
        out = calibrate_trace(str(tmp_path / "t.jsonl"), compliance={})
        assert out.comparison["supported"], out.comparison["statement"]
        assert {"c2", "c3"} <= set(out.comparison["compliances"])
        z, _d2 = tg.errors_against_truth(out, x)
        z_all.append(z)
        rigid = calibrate_trace(str(tmp_path / "t.jsonl"), accept_poor_fit=True)
        # the rigid fit's geometry against the truth's (what the compliant fit recovers)
        names = [n for n, s in zip(out.result.names, out.result.status) if s.identifiable]
        r = rigid.result
        for n in names:
            if n in r.names and r.status[r.names.index(n)].identifiable:
                j, k = out.result.names.index(n), r.names.index(n)
                z_rigid.append((r.x[k] - out.result.x[j]) / r.std[k])
    z = np.concatenate(z_all)
    rms = float(np.sqrt(np.mean(z ** 2)))
    print(f"compliant: RMS error/std {rms:.3f} over {z.size}; rigid geometry off by "
          f"{np.sqrt(np.mean(np.square(z_rigid))):.1f} std RMS")
    assert 0.8 < rms < 1.3 and np.mean(np.abs(z) < 2) > 0.9
    assert np.sqrt(np.mean(np.square(z_rigid))) > 3 and np.max(np.abs(z_rigid)) > 10


def test_a_rigid_arm_is_unchanged_when_compliance_is_offered(tmp_path, capsys):
    export_and_import(tmp_path, arm(), 7400)
    plain = calibrate_trace(str(tmp_path / "t.jsonl"))
    rc = app_module.main(["batch", str(tmp_path / "t.jsonl"), "--out", str(tmp_path / "p.json"),
                          "--compliance", "--report", str(tmp_path / "r.html")])
    out = capsys.readouterr().out
    assert rc == 0
    assert "compliance not supported" in out and "by cross-validation over" in out
    assert "written: the rigid model" in out and "model compliant:" in out
    doc = json.loads((tmp_path / "p.json").read_text())
    assert not any(k.startswith("c") and k[1:].isdigit() for k in doc["parameters"])
    assert doc["model_comparison"]["supported"] is False
    # the report says which model was written and why (the same sentence)
    html = (tmp_path / "r.html").read_text()
    assert "the rigid model written" in html and "by cross-validation over" in html
    for j, n in enumerate(plain.result.names):
        assert doc["parameters"][n]["value"] == plain.result.x[j]


def test_compliance_needs_a_urdf_robot(tmp_path, capsys):
    rc = app_module.main(["trace", "generate", "--robot", str(URDF.parent / "ur5-like-hayati.toml"),
                          "--method", "sm-position", "--count", "30",
                          "--out", str(tmp_path / "u.jsonl")])
    assert rc == 0
    rc = app_module.main(["batch", str(tmp_path / "u.jsonl"), "--out", str(tmp_path / "p.json"),
                          "--compliance", "--report", str(tmp_path / "r.html")])
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: --compliance needs a URDF robot")


def test_a_compliant_calibration_is_not_exported_as_a_urdf(tmp_path, capsys):
    """The URDF holds the geometry alone; a compliant calibration's geometry was fitted
    with its compliances: refused in one line, nothing written."""
    export_and_import(tmp_path, compliant_arm(), 7300)
    p = tmp_path / "p.json"
    assert app_module.main(["batch", str(tmp_path / "t.jsonl"), "--out", str(p),
                            "--compliance"]) == 0
    assert json.loads(p.read_text())["model_comparison"]["supported"]
    capsys.readouterr()
    rc = app_module.main(["params", "export", str(p), "--urdf", str(tmp_path / "c.urdf")])
    err = capsys.readouterr().err
    assert rc == 2 and "a compliant calibration (c2" in err and err.count("\n") == 1, err
    assert "batch without --compliance" in err and not (tmp_path / "c.urdf").exists()
