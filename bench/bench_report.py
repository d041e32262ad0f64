"""The HTML report's cost (issue 24: the report <= 0.5 s of CPU): the station's report of
an AGEBOT sm-distance-tilt session, written by the package as it is ("now") and by the
previous implementation ("before": the figures module as of commit c327d63, read from
the repository's history with ``git show``, the
Jinja2 environment built per report, the garbage collector left on), same outcome,
same validation, same events.

    python bench/bench_report.py [--trace T] [--rounds 7] [--cold 3]

Without ``--trace`` a simulated session is run first (``app.py run --simulate --robot
agebot-sm --method sm-distance-tilt``, about a minute) and its trace used. The trace is
calibrated once in-process (as ``app.py batch`` does); then per round, interleaved
after a warm-up round, each variant writes the report (``write_report``: context,
sections, figures, template, atomic write), each from a heap collected just before
(untimed: a report pays for its own garbage, not the other variant's); CPU seconds
(process time) and wall time.
Both reports must say the same before a time is printed: the HTML without its
figures and time stamps equal, the same number of figures, and each figure citing the
same figures of the source report in its caption (a figure may change its form, e.g.
the parameter paths since issue 24, so its own alt text and caption may differ; both
are printed when they do). ``--cold N``: also N
fresh processes per variant, each timing its first report (imports of matplotlib and
Jinja2 included), interleaved.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import re
import statistics
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from station.outputs import report, report_sections  # noqa: E402

#: the last commit before the report's rework (issue 24): its figures module is "before"
BEFORE_COMMIT = "c327d63"
IMG = re.compile(r'data:image/(?:png|svg\+xml);base64,[A-Za-z0-9+/=]+')  # PNG before, SVG now
FIGURE = re.compile(r'<figure><img src="[^"]*" alt="([^"]*)"><figcaption>(.*?)</figcaption>'
                    r'</figure>', re.S)
CITED = re.compile(r"Fig\. \d+(?:, \d+)*")
STAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(?:\.\d+)?Z")


def _before_module():
    """``station/outputs/report_figures.py`` as of :data:`BEFORE_COMMIT` (git history)."""
    src = subprocess.run(["git", "-C", str(ROOT), "show",
                          f"{BEFORE_COMMIT}:station/outputs/report_figures.py"],
                         capture_output=True, text=True)
    if src.returncode != 0:
        sys.exit(f"error: cannot read the previous report figures from git ({BEFORE_COMMIT}): "
                 f"{src.stderr.strip() or 'git failed'}; run from a clone with its history")
    mod = types.ModuleType("report_figures_before")
    exec(compile(src.stdout, f"{BEFORE_COMMIT}:station/outputs/report_figures.py", "exec"),
         mod.__dict__)
    return mod


@contextlib.contextmanager
def variant(name: str):
    """The package as it is ("now") or with the previous implementation ("before")."""
    if name == "now":
        yield
        return
    saved = (report.figs, report_sections.figs, report.template_environment,
             report.collector_paused)
    before = _before_module()
    report.figs = report_sections.figs = before
    report.template_environment = report.template_environment.__wrapped__
    report.collector_paused = contextlib.nullcontext
    try:
        yield
    finally:
        (report.figs, report_sections.figs, report.template_environment,
         report.collector_paused) = saved


def load(trace: str):
    """The outcome and what the station hands the report (validation, session)."""
    from station.fitting.batch import calibrate_trace

    outcome = calibrate_trace(trace)
    return outcome, {"validation": outcome.validation,
                     "session": {"robot": "agebot-sm", "method": "sm-distance-tilt"}}


def session_trace(tmp: Path) -> str:
    out = tmp / "run"
    subprocess.run([sys.executable, str(ROOT / "app.py"), "run", "--simulate", "--robot",
                    "agebot-sm", "--method", "sm-distance-tilt", "--out", str(out)],
                   check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
    return str(out / "trace.jsonl")


def said(html: str) -> str:
    """The report's text without its figures and time stamps."""
    return STAMP.sub("T", FIGURE.sub("FIGURE", html))


def figures_alike(before: str, now: str) -> list[str]:
    """The two reports' figures in order: the same number, each citing the same figures
    of the source report; returns the lines to print where a figure's alt or caption
    changed (a figure re-formed), raises SystemExit where they do not match."""
    b, n = FIGURE.findall(before), FIGURE.findall(now)
    if len(b) != len(n) or len(IMG.findall(before)) != len(IMG.findall(now)):
        raise SystemExit(f"figures differ: before {len(b)}, now {len(n)}")
    changed = []
    for (alt_b, cap_b), (alt_n, cap_n) in zip(b, n):
        if CITED.findall(cap_b) != CITED.findall(cap_n):
            raise SystemExit(f"figure {alt_n!r} cites {CITED.findall(cap_n)}, before "
                             f"{alt_b!r} cited {CITED.findall(cap_b)}")
        if (alt_b, cap_b) != (alt_n, cap_n):
            changed.append(f"re-formed figure: before {alt_b!r}, now {alt_n!r}")
    return changed


def cold(trace: str, name: str) -> float:
    """CPU seconds of the first report in a fresh process (imports included)."""
    code = (f"import sys, time; sys.path.insert(0, {str(ROOT / 'bench')!r}); "
            "import bench_report as b; o, kw = b.load(sys.argv[1]); "
            "from station.outputs import report; "
            "t = time.process_time(); "
            f"cm = b.variant({name!r}); cm.__enter__(); "
            "report.write_report(sys.argv[2], o, **kw); "
            "print(time.process_time() - t)")
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, "-c", code, trace, str(Path(tmp) / "r.html")],
                           check=True, cwd=ROOT, capture_output=True, text=True)
    return float(r.stdout.split()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trace", help="a session's trace (default: run a simulated session)")
    ap.add_argument("--rounds", type=int, default=7, help="timed rounds after the warm-up")
    ap.add_argument("--cold", type=int, default=3, help="fresh processes per variant")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        trace = args.trace or session_trace(tmp)
        outcome, kw = load(trace)
        names = ("before", "now")
        cpu = {n: [] for n in names}
        wall = {n: [] for n in names}
        text = {}
        for rnd in range(args.rounds + 1):                 # round 0: warm-up
            for name in (names if rnd % 2 else names[::-1]):
                path = tmp / f"{name}.html"
                with variant(name):
                    # each report starts from a collected heap: otherwise it runs on the
                    # other variant's uncollected garbage, its memory not yet freed
                    # (measured: "now" 0.41-0.64 s so, 0.40-0.43 s after a collection)
                    gc.collect()
                    c, w = time.process_time(), time.perf_counter()
                    report.write_report(path, outcome, **kw)
                    c, w = time.process_time() - c, time.perf_counter() - w
                text[name] = path.read_text(encoding="utf-8")
                if rnd:
                    cpu[name].append(c)
                    wall[name].append(w)
        if said(text["before"]) != said(text["now"]):
            raise SystemExit("the two reports do not say the same")
        changed = figures_alike(text["before"], text["now"])
        n_img = {n: len(IMG.findall(t)) for n, t in text.items()}
        colds = {n: [] for n in names}
        for i in range(args.cold):
            for name in (names if i % 2 else names[::-1]):
                colds[name].append(cold(trace, name))
    res = outcome.result
    print(f"trace {Path(trace).name}: {outcome.model.n_poses} poses, {len(res.history)} "
          f"iterations, {res.n_identifiable} identifiable, {n_img['now']} figures; "
          f"{args.rounds} rounds")
    print(f"{'variant':8s} {'CPU s min':>10s} {'median':>8s} {'wall s median':>14s} "
          f"{'first in a process':>19s} {'HTML kB':>8s}")
    for name in names:
        first = f"{statistics.median(colds[name]):.3f}" if colds[name] else "-"
        print(f"{name:8s} {min(cpu[name]):10.3f} {statistics.median(cpu[name]):8.3f} "
              f"{statistics.median(wall[name]):14.3f} {first:>19s} "
              f"{len(text[name].encode()) / 1024:8.0f}")
    ratio = [n / b for n, b in zip(cpu["now"], cpu["before"])]
    line = (f"now/before CPU per round: median {statistics.median(ratio):.2f} "
            f"(min {min(ratio):.2f}, max {max(ratio):.2f})")
    if args.cold:
        first = statistics.median(colds["now"]) / statistics.median(colds["before"])
        line += f"; first in a process {first:.2f}"
    print(line)
    for c in changed:
        print(c)
    return 0


if __name__ == "__main__":
    sys.exit(main())
