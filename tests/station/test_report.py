"""The HTML calibration report (station/outputs/report.py): one self-contained file,
written atomically, escaped, with the figures embedded as SVG."""
import base64
import json
import os
import re
import shutil
import warnings
import xml.etree.ElementTree as ET
from html.parser import HTMLParser

import markupsafe
import pytest

import app
from station.fitting.batch import calibrate_trace
from station.outputs.report import ReportError, write_report

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
TRACES = os.path.join(ROOT, "fixtures", "traces")
SVG_NS = "{http://www.w3.org/2000/svg}"
IMG = re.compile(r'<img src="data:image/svg\+xml;base64,([A-Za-z0-9+/=]+)"')
GROUPS = ("Identifiable (", "Not identifiable, without influence (",
          "Not identifiable, with influence (")
VALIDATION = [
    {"channel": "dx", "unit": "mm", "n": 12, "rms_before": 31.25, "rms_after": 0.0417,
     "max_before": 77.5, "max_after": 0.0931},
    {"channel": "dy", "unit": "mm", "n": 12, "rms_before": 18.5, "rms_after": 0.0388,
     "max_before": 40.25, "max_after": 0.0875},
]
# a session's plan event: 79 poses (the raw JSON would be ~20000 characters)
PLAN_EVENT = {"record": "event", "t": "2026-01-02T09:59:00Z", "kind": "plan",
              "message": "planned 79 poses (13 held out for validation; eq. 60 minimum 33 poses)",
              "replace": True,
              "poses": [{"index": i, "qm": [30.85 + i, 161.98, -182.75, -130.29],
                         "target": [-0.0119, -0.0357, -0.1144, 0.0602],
                         "use": "validation" if i % 6 == 5 else "fit", "round": 0}
                        for i in range(79)]}
EVIL = "<script>alert('x')</script> drive 2 & \"3\""


def calibrate(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate_trace(str(path))


class Tags(HTMLParser):
    """Counts open/close tags so that the structure can be checked."""

    VOID = frozenset({"meta", "img", "br", "hr", "link", "input"})

    def __init__(self):
        super().__init__()
        self.stack, self.errors, self.tags = [], [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:]}")
        else:
            self.stack.pop()


def check_html(text):
    assert text.startswith("<!DOCTYPE html>")
    assert text.rstrip().endswith("</html>")
    p = Tags()
    p.feed(text)
    p.close()
    assert not p.errors, p.errors[:5]
    assert not p.stack, p.stack
    # self-contained: no scripts, no stylesheets or images from elsewhere
    names = [t for t, _ in p.tags]
    assert "script" not in names and "link" not in names and "iframe" not in names
    for _, attrs in p.tags:
        for key in ("src", "href"):
            assert not attrs.get(key, "data:").lower().startswith(("http:", "https:", "//")), attrs
    return p


def svgs(text):
    """The report's figures: each an SVG document that parses, with its text as <text>
    (drawn by the browser, not as glyph paths) and nothing from elsewhere (its links
    only to its own definitions, no images, no scripts)."""
    out = [base64.b64decode(b, validate=True) for b in IMG.findall(text)]
    for svg in out:
        root = ET.fromstring(svg)
        assert root.tag == SVG_NS + "svg"
        assert any(e.text and e.text.strip() for e in root.iter(SVG_NS + "text"))
        for e in root.iter():
            assert e.tag not in (SVG_NS + "script", SVG_NS + "image", SVG_NS + "foreignObject")
            for key, value in e.attrib.items():
                if key.endswith("href"):
                    assert value.startswith("#"), (key, value)
    return out


@pytest.fixture(scope="module")
def sm_report(tmp_path_factory):
    """sm-self-redundancy (all three identifiability classes), with an event
    recorded in the trace, one given, validation and a session."""
    d = tmp_path_factory.mktemp("sm")
    trace = d / "sm-self-redundancy.jsonl"
    shutil.copyfile(os.path.join(TRACES, "sm-self-redundancy.jsonl"), trace)
    with open(trace, "a", encoding="utf-8") as f:
        f.write(json.dumps({"record": "event", "t": "2026-01-02T10:00:00Z", "kind": "fault",
                            "message": "recorded <b>fault</b> & retry"}) + "\n")
        f.write(json.dumps(PLAN_EVENT) + "\n")
    outcome = calibrate(trace)
    out = write_report(d / "report.html", outcome, validation=VALIDATION,
                       events=[{"t": "2026-01-02T10:05:00Z", "kind": "operator", "message": EVIL}],
                       session={"station config": "sim-sm.toml", "operator": "<Jan & Eva>",
                                "devices": {"drive": "sim-cia402", "inclinometer": "sim"}},
                       title="Calibration of <AGEBOT>")
    return outcome, out, out.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def pm_report(tmp_path_factory):
    outcome = calibrate(os.path.join(TRACES, "pm-ik.jsonl"))
    out = write_report(tmp_path_factory.mktemp("pm") / "pm.html", outcome)
    return outcome, out, out.read_text(encoding="utf-8")


def test_sm_report_content(sm_report):
    outcome, path, text = sm_report
    assert path.is_file() and path.suffix == ".html"
    check_html(text)
    for name in outcome.result.names:
        assert f'<td class="name">{name}</td>' in text
    for group in GROUPS:  # sm-self-redundancy has all three classes
        assert group in text
    assert len(svgs(text)) >= 6  # 4 iteration figures, residuals, validation
    assert "sm-self-redundancy.jsonl" in text and outcome.document is None
    assert "Eq. 60 minimum poses" in text and "Condition number" in text
    for key in ("dx", "dy"):
        assert f'<td class="name">{key}</td>' in text
    # the title is escaped too
    assert "Calibration of &lt;AGEBOT&gt;" in text and "<AGEBOT>" not in text


def test_validation_table(sm_report):
    _, _, text = sm_report
    sec = text[text.index('<section id="validation">'):]
    sec = sec[:sec.index("</section>")]
    for row in VALIDATION:
        for key in ("channel", "unit", "n", "rms_before", "rms_after", "max_before", "max_after"):
            assert f">{row[key]}<" in sec, (key, row[key])
    assert ">-99.87 %<" in sec and ">-99.79 %<" in sec  # RMS change of dx, dy
    assert len(svgs(sec)) == 1


def test_events_and_session_are_escaped(sm_report):
    _, _, text = sm_report
    assert "<script" not in text
    assert str(markupsafe.escape(EVIL)) in text
    assert "&lt;script&gt;alert(&#39;x&#39;)&lt;/script&gt; drive 2 &amp; &#34;3&#34;" in text
    assert "recorded &lt;b&gt;fault&lt;/b&gt; &amp; retry" in text  # from the trace
    assert "&lt;Jan &amp; Eva&gt;" in text and "sim-cia402" in text


def test_pm_report(pm_report):
    outcome, _, text = pm_report
    check_html(text)
    for name in outcome.result.names:
        assert f'<td class="name">{name}</td>' in text
    assert GROUPS[0] in text and GROUPS[2] in text and GROUPS[1] not in text
    assert len(svgs(text)) >= 5
    assert "q3_off and k3" in text  # the method's note
    assert 'id="validation"' not in text and 'id="events"' not in text


def test_batch_cli_writes_the_report(tmp_path, capsys):
    params, report = tmp_path / "p.json", tmp_path / "r.html"
    rc = app.main(["batch", os.path.join(TRACES, "sm-distance-tilt.jsonl"), "--out", str(params),
                   "--report", str(report)])
    assert rc == 0
    assert "report written to" in capsys.readouterr().out
    text = report.read_text(encoding="utf-8")
    check_html(text)
    assert len(svgs(text)) >= 5
    assert json.loads(params.read_text())["checksum"] in text  # the parameter file it goes with
    assert "Base frame" in text  # sm-distance-tilt's frame statement
    assert sorted(os.listdir(tmp_path)) == ["p.json", "r.html"]


def test_unwritable_path_is_a_clear_error_and_leaves_nothing(tmp_path, sm_report):
    outcome = sm_report[0]
    missing = tmp_path / "no-such-folder" / "r.html"
    with pytest.raises(ReportError, match="report .*no-such-folder.*does not exist"):
        write_report(missing, outcome)
    assert not missing.parent.exists()
    target = tmp_path / "a-folder"  # an existing directory cannot be replaced by the file
    target.mkdir()
    (target / "keep.txt").write_text("x")
    with pytest.raises(ReportError, match="cannot write the report .*a folder"):
        write_report(target, outcome)
    assert sorted(os.listdir(tmp_path)) == ["a-folder"]
    assert os.listdir(target) == ["keep.txt"]


def test_failed_write_leaves_no_partial_file(tmp_path, sm_report, monkeypatch):
    """A failure while writing (disk full, ...) removes the temporary file and
    keeps a previous report as it was."""
    import station.outputs.params_file
    import station.outputs.report

    monkeypatch.setattr(station.outputs.report, "render_report", lambda *a, **k: "<!DOCTYPE html>" * 1000)
    old = tmp_path / "r.html"
    old.write_text("previous report")

    def full(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(station.outputs.params_file.os, "replace", full)
    with pytest.raises(ReportError, match="No space left on device"):
        write_report(old, sm_report[0])
    assert os.listdir(tmp_path) == ["r.html"] and old.read_text() == "previous report"


def test_batch_cli_unwritable_report_is_one_line(tmp_path, capsys, monkeypatch):
    import station.outputs.report

    monkeypatch.setattr(station.outputs.report, "render_report", lambda *a, **k: "<!DOCTYPE html>")
    bad = tmp_path / "missing" / "r.html"
    rc = app.main(["batch", os.path.join(TRACES, "sm-distance-tilt.jsonl"),
                   "--out", str(tmp_path / "p.json"), "--report", str(bad)])
    err = capsys.readouterr().err
    assert rc != 0
    assert err.startswith("error: cannot write the report") and len(err.strip().splitlines()) == 1
    assert not bad.parent.exists()


class Cells(HTMLParser):
    """The text of every table cell."""

    def __init__(self):
        super().__init__()
        self.cells, self._cell = [], None

    def handle_starttag(self, tag, attrs):
        if tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self.cells.append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def test_no_table_cell_is_long_and_the_plan_is_its_own_table(sm_report):
    """The 79-pose plan is a table of its own (index, qm, target, held out), not raw
    JSON in the events table; no cell anywhere exceeds CELL_MAX characters."""
    from station.outputs.report_context import CELL_MAX

    _, _, text = sm_report
    p = Cells()
    p.feed(text)
    assert p.cells and max(map(len, p.cells)) <= CELL_MAX, max(p.cells, key=len)[:80]
    sec = text[text.index('<section id="events">'):]
    sec = sec[:sec.index("</section>")]
    assert '"qm"' not in sec and "&#34;qm&#34;" not in sec  # no JSON
    plan = sec[sec.index('<table class="plan">'):]
    plan = plan[:plan.index("</table>")]
    assert plan.count("<tr") == 80  # header + 79 poses
    assert plan.count("<td>held out</td>") == 13
    assert ">30.85, 161.98, -182.75, -130.29<" in plan
    # the target as people read it (issue 44): mm and degrees, each coordinate named
    assert ">x -11.9 mm, y -35.7 mm, z -114.4 mm, phi 3.449°<" in plan, plan[:600]
    assert "SI: m, rad" not in plan


def test_summary_has_the_validation_headline(sm_report):
    _, _, text = sm_report
    sec = text[text.index('<section id="summary">'):]
    sec = sec[:sec.index("</section>")]
    assert "<th>Validation</th>" in sec
    assert "dx RMS 31.25 mm \u2192 0.0417 mm over 12 held-out poses" in sec


def test_validation_after_bars_are_visible():
    """"After" errors 1000 times smaller than "before" still get bars of visible
    height (log axis), in the display units."""
    from station.outputs.report_figures import validation_figure
    from station.outputs.units import MM_DEG

    rows = [{"channel": "distance", "unit": "m", "n": 13, "rms_before": 0.0476,
             "rms_after": 4.71e-06, "max_before": 0.12, "max_after": 1.1e-05},
            {"channel": "tilt", "unit": "rad", "n": 13, "rms_before": 0.243,
             "rms_after": 6.27e-05, "max_before": 0.5, "max_after": 1.5e-4}]
    fig = validation_figure(rows, MM_DEG)
    fig.canvas.draw()
    for ax, v in zip(fig.axes, rows):
        bars = {c.get_label(): c for c in ax.containers}
        assert set(bars) == {"before", "after"}
        for when in ("before", "after"):
            heights = [r.get_window_extent().height for r in bars[when].patches]
            assert min(heights) >= 5, (v["channel"], when, heights)  # pixels
        # the labels are the values in display units (mm, degrees)
        labels = [t.get_text() for t in ax.texts]
        assert format(v["rms_after"] * MM_DEG.unit(v["unit"])[1], ".3g") in labels


def test_the_parameter_figure_draws_every_calibrated_parameter_s_path(sm_report, monkeypatch):
    """The parameters figure (a few panels of scaled paths, not a panel per parameter):
    each identifiable parameter once in a legend, with its scale D in its unit, its key
    drawn as its path is (colour, dash, width, marker), and its drawn path is its
    iterations exactly, (xi(k) - xi_final) / D, within [-1, 1]."""
    import numpy as np

    from station.outputs import report_figures, report_plotting
    from station.outputs.report_context import ReportContext

    outcome = sm_report[0]
    ctx = ReportContext(outcome)
    hist = list(outcome.result.history)
    drawn = []
    monkeypatch.setattr(report_plotting, "img", lambda fig, alt, caption: drawn.append(fig))
    report_figures._fig_parameters(ctx, hist)
    (fig,) = drawn
    paths = np.vstack([outcome.result.x0] + [h.x for h in hist])
    seen = []
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        entries = report_plotting.legend_entries(ax)
        assert entries
        for key, text in entries:
            name = text.get_text().split(" (1 = ")[0]
            seen.append(name)
            j = ctx.names.index(name)
            (path,) = [ln for ln in ax.get_lines() if ln.get_label() == text.get_text()]
            y = path.get_ydata()
            assert (key.get_color(), key.get_linestyle(), key.get_linewidth(),
                    key.get_marker()) == (path.get_color(), path.get_linestyle(),
                                          path.get_linewidth(), path.get_marker())
            scale = np.max(np.abs(paths[:, j] - ctx.x[j]))
            assert f"(1 = {scale:.3g}" in text.get_text()
            unit = ctx.units.get(name, "")
            assert text.get_text().endswith(f" {unit})" if unit else ")")
            assert np.max(np.abs(y)) <= 1.0 + 1e-12
            assert np.allclose(ctx.x[j] + scale * np.asarray(y), paths[:, j], rtol=0,
                               atol=1e-12 * max(1.0, abs(ctx.x[j])))
    identifiable = [n for n, g in zip(ctx.names, ctx.groups) if g == "identifiable"]
    assert sorted(seen) == sorted(identifiable) and len(identifiable) > 4


@pytest.mark.parametrize("ncol, options", [
    (1, {}), (1, {"anchor": (1.0, 1.0), "handlelength": 1.6, "borderaxespad": 0.2}),
    (2, {})])
def test_the_report_legend_is_laid_out_as_matplotlib_s(ncol, options):
    """The kit's legend (a line and a text per entry, placed once) puts every key and
    label where matplotlib's own legend does, to 0.05 pt: the same rows, the entries in
    the same columns (matplotlib's columns as wide as their labels, the kit's
    LEGEND_COLUMN wide: compared in the first column)."""
    import numpy as np

    from station.outputs import report_plotting as kit

    opts = {"anchor": (1.01, 1.0), "handlelength": 2.0, "borderaxespad": 0.5, **options}

    @kit.styled(8)
    def draw(ours):
        fig = kit.figure(10.0, 3.6, right=kit.legend_right(5 * ncol), left=0.8)
        ax = fig.subplots()
        for n in range(5 * ncol):
            ax.semilogy(np.arange(6), 10.0 ** (np.arange(6) - n), marker="o", ms=2.5,
                        label=f"p{n} (1 = {0.3 * n:.3g} rad)", **kit.line_style(n))
        if ours:
            kit.legend(ax, ncol=ncol, **opts)
        else:
            leg = ax.legend(fontsize=7, ncol=ncol, loc="upper left", frameon=False,
                            bbox_to_anchor=opts["anchor"], handlelength=opts["handlelength"],
                            borderaxespad=opts["borderaxespad"])
        fig.canvas.draw()
        pairs = (kit.legend_entries(ax) if ours
                 else list(zip(leg.get_lines(), leg.get_texts())))
        x0, y0 = ax.transAxes.transform(opts["anchor"])
        pt = 72 / fig.dpi
        out = []
        for key, text in pairs:
            xy = key.get_transform().transform(np.c_[key.get_xdata(), key.get_ydata()])
            box = text.get_window_extent()
            out.append((text.get_text(), (xy[0][0] - x0) * pt, (xy[-1][0] - x0) * pt,
                        (xy[0][1] - y0) * pt, (box.x0 - x0) * pt,
                        ((box.y0 + box.y1) / 2 - y0) * pt))
        return out

    ours, theirs = draw(True), draw(False)
    assert [o[0] for o in ours] == [t[0] for t in theirs] and len(ours) == 5 * ncol
    first = ours[0][1]
    for o, t in zip(ours, theirs):
        assert abs(o[3] - t[3]) < 0.05 and abs(o[5] - t[5]) < 0.05, (o, t)   # rows
        assert (o[1] > first + 1) == (t[1] > first + 1), (o, t)               # columns
        if o[1] < first + 1:
            assert np.allclose(o[1:5:3], t[1:5:3], atol=0.05), (o, t)
            assert abs(o[2] - t[2]) < 0.05, (o, t)


def test_units_policy():
    """People read mm and degrees (or the config's [display]); the config's choices
    are the units module's."""
    from drivers.config import DISPLAY_ANGLES, DISPLAY_LENGTHS, parse_station_config
    from station.outputs.units import ANGLES, LENGTHS, MM_DEG, Units, describe_error, from_config
    from drivers.snapshot import UnstableReading, Violation

    assert set(DISPLAY_LENGTHS) == set(LENGTHS) and set(DISPLAY_ANGLES) == set(ANGLES)
    assert MM_DEG.text(0.00228, "m") == "2.28 mm"
    assert MM_DEG.text(0.5, "rad", ".3g") == "28.6\u00b0"
    assert MM_DEG.text(1e-4, "rad/u", ".3g") == "0.00573\u00b0/u"
    assert MM_DEG.text(3.0, "u") == "3 u"
    e = UnstableReading([Violation("draw-wire", "distance", "drift", 0.00228, 0.002)])
    assert describe_error(e) == ("draw-wire: unstable reading: draw-wire channel 'distance': drift "
                                 "2.28 mm exceeds the limit 2.00 mm")
    base = {"robot": "agebot-sm", "canopen": {"interface": "virtual", "nodes": [1, 2, 3, 4],
                                              "increments_per_unit": [1, 1, 1, 1]}}
    assert from_config(parse_station_config(base)) == MM_DEG
    cfg = parse_station_config({**base, "display": {"length": "m", "angle": "rad"}})
    assert from_config(cfg) == Units("m", "rad")
    with pytest.raises(Exception, match="display.*furlong|furlong"):
        parse_station_config({**base, "display": {"length": "furlong"}})


def test_the_draw_wire_s_scale_is_said_in_the_report_and_the_wizard(tmp_path, qtbot):
    """Issue 44: the draw-wire's 1 % scale, which every calibrated length carries, was only
    on the console; the report and the Calibrate page said a std of 0.02 mm without it.
    The captured base origin's note names AGEBOT's parameters only on AGEBOT's arm."""
    from station.gui.results import CalibrationView
    from station.outputs.fit_summary import format_table, operator_notes

    outcome = calibrate(os.path.join(TRACES, "sm-distance-tilt.jsonl"))
    notes = operator_notes(outcome)
    assert any("draw-wire's scale" in n and "1 %" in n for n in notes), notes
    assert any("captured base origin" in n for n in notes)
    text = write_report(tmp_path / "r.html", outcome).read_text(encoding="utf-8")
    assert "draw-wire&#39;s scale" in text or "draw-wire's scale" in text
    view = CalibrationView()
    qtbot.addWidget(view)
    view.show_outcome(outcome)
    assert "draw-wire's scale" in view.notes.text()
    assert "draw-wire's scale" in format_table(outcome)


def test_a_robot_file_s_arm_is_not_told_agebot_s_parameters(tmp_path, qtbot):
    from station.gui.results import CalibrationView

    trace = tmp_path / "t.jsonl"
    rc = app.main(["trace", "generate", "--robot",
                   os.path.join(os.path.dirname(TRACES), "robots", "ur5-like-hayati.toml"),
                   "--method", "sm-distance-tilt", "--seed", "3", "--out", str(trace)])
    assert rc == 0
    outcome = calibrate(trace)
    view = CalibrationView()
    qtbot.addWidget(view)
    view.show_outcome(outcome)
    assert "theta0" not in view.notes.text() and "draw-wire's scale" in view.notes.text()
