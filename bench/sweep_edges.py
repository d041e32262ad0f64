#!/usr/bin/env python3
"""Adversarial sweep of the command line (issue 27): a user's mistakes, outputs that
would destroy inputs, hung devices and silently wrong commands, each run as
``python app.py ...`` in a subprocess of a checkout.

    python bench/sweep_edges.py                     # this checkout, ~5 min
    python bench/sweep_edges.py --root /tmp/old     # another checkout (before/after)
    python bench/sweep_edges.py --only out- -v      # cases whose name starts so
    python bench/sweep_edges.py --only data- -v     # the data cases only, ~6 min
    python bench/sweep_edges.py --only u43- -v      # a URDF's and a CSV's (issue 43)

Each case says what a careful tool does: ``refuse`` (a one-line ``error: ...`` on
stderr, exit 2), ``ok`` (exit 0) or ``either``. The ``data-`` cases are measurements
with a user's mistakes (units, signs, mirrored or swapped axes, joint columns, joint
maps, chains) of robot files (``data-rf-``) and a URDF robot (``data-urdf-``), each
``trace import`` then ``batch``; the accepted ones are checked against the truth that
drew them (see ``serial_data_cases``). Counted:

- wrong:     exit 0 where the case must be refused, or an accepted answer that is not
             the truth's (a confident wrong answer)
- changed:   an input file changed (sha256), or a device node turned into a file
- hang:      no exit within 20 s
- traceback: a Python traceback on stderr
- messy:     refused, but not with one ``error: ...`` line (or exit 0 where refused
             is also fine but the exit code is neither 0 nor 2)

A run with ``--json FILE`` also writes every case's outcome.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HANG_S = 20.0
OWN: dict = {}      # private copy -> its source: put back after each output case


@dataclass
class Case:
    name: str
    argv: list
    expect: str = "refuse"          # refuse | ok | either
    inputs: list = field(default_factory=list)
    nodes: list = field(default_factory=list)     # device nodes that must stay devices
    absent: list = field(default_factory=list)    # paths that must not exist afterwards
    timeout: float = HANG_S                       # per command
    then: list = field(default_factory=list)      # further commands, each run if the last exits 0
    check: object = None    # accepted: check(stdout) -> (why the answer is wrong or '', figures)


def sha(path):
    try:
        with open(path, "rb") as f:
            return hashlib.sha256(f.read()).hexdigest()
    except OSError as e:
        return f"unreadable {e.errno}"


def setup(root: str, d: str) -> dict:
    """The files the cases read: fixtures copied into ``d`` plus a few made here."""
    fx = os.path.join(root, "fixtures")
    p = {}

    def cp(src, name):
        dst = os.path.join(d, name)
        shutil.copy(os.path.join(fx, src), dst)
        p[name] = dst
        return dst

    cp("traces/sm-distance-tilt.jsonl", "t.jsonl")
    cp("traces/pm-fk.jsonl", "pm.jsonl")
    cp("robots/ur5-like-dh.toml", "ur5.toml")
    cp("robots/scara-like.toml", "scara.toml")
    cp("robots/m10ia-like.urdf", "m10.urdf")
    cp("truth/agebot-sm.json", "truth-sm.json")
    cp("truth/agebot-pm.json", "truth-pm.json")
    cp("stations/sim-sm.toml", "sim-sm.toml")
    env = dict(os.environ, PYTHONPATH=root)

    def app(*a):
        r = subprocess.run([sys.executable, os.path.join(root, "app.py"), *a], cwd=d, env=env,
                           capture_output=True, text=True, timeout=300)
        if r.returncode:
            raise RuntimeError(f"setup: app.py {' '.join(a)}: {r.stderr[-500:]}")
        return r

    p["params"] = os.path.join(d, "p.json")
    app("batch", p["t.jsonl"], "--out", p["params"])
    p["ur5.jsonl"] = os.path.join(d, "ur5.jsonl")
    app("trace", "generate", "--robot", p["ur5.toml"], "--method", "sm-position", "--out",
        p["ur5.jsonl"], "--noise", "position=1e-5")
    p["ur5-params"] = os.path.join(d, "ur5-p.json")
    app("batch", p["ur5.jsonl"], "--out", p["ur5-params"])
    # a CSV of the ur5 trace (trace import's input)
    rows = [json.loads(x) for x in open(p["ur5.jsonl"])]
    poses = [r for r in rows if r.get("record") == "pose"]
    csv = os.path.join(d, "ur5.csv")
    with open(csv, "w") as f:
        f.write(",".join(f"qm{i + 1}" for i in range(6)) + ",x,y,z\n")
        for r in poses:
            f.write(",".join(repr(v) for v in r["qm"] + r["position"]) + "\n")
    p["ur5.csv"] = csv
    # device nodes: a private /dev/null and /dev/full (root), else FIFOs
    for name, dev in (("null", (1, 3)), ("full", (1, 7))):
        path = os.path.join(d, f"dev-{name}")
        try:
            os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(*dev))
        except (PermissionError, OSError):
            os.mkfifo(path)
        p[f"dev-{name}"] = path
    p["fifo"] = os.path.join(d, "fifo")
    os.mkfifo(p["fifo"])
    os.mkdir(os.path.join(d, "folder"))
    p["folder"] = os.path.join(d, "folder")
    os.symlink(p["t.jsonl"], os.path.join(d, "link.jsonl"))
    p["link"] = os.path.join(d, "link.jsonl")
    return p


def robot_variant(p, d, name, edit):
    """A copy of ur5.toml changed by ``edit(text) -> text`` (str) or bytes."""
    text = open(p["ur5.toml"], encoding="utf-8").read()
    out = edit(text)
    path = os.path.join(d, name)
    with open(path, "wb") as f:
        f.write(out if isinstance(out, bytes) else out.encode("utf-8"))
    return path


def params_variant(p, d, name, edit, source="params"):
    """A copy of a parameter file edited as JSON text or object, checksum recomputed."""
    doc = json.load(open(p[source]))
    res = edit(doc)
    if isinstance(res, str):      # raw text: re-sign over the parsed body
        text = res
    else:
        body = {k: v for k, v in doc.items() if k != "checksum"}
        canon = json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True)
        doc["checksum"] = "sha256:" + hashlib.sha256(canon.encode()).hexdigest()
        text = json.dumps(doc)
    path = os.path.join(d, name)
    with open(path, "w") as f:
        f.write(text)
    return path


def station_variant(p, d, name, edit):
    text = open(p["sim-sm.toml"], encoding="utf-8").read()
    path = os.path.join(d, name)
    out = edit(text)
    with open(path, "wb") as f:
        f.write(out if isinstance(out, bytes) else out.encode("utf-8"))
    return path


def truth_variant(p, d, name, edit):
    doc = json.load(open(p["truth-sm.json"]))
    edit(doc)
    path = os.path.join(d, name)
    with open(path, "w") as f:
        json.dump(doc, f)
    return path


def cases(p: dict, d: str, hung_port: int, dead_port: int) -> list[Case]:
    C = []
    T, R, TR = p["t.jsonl"], p["ur5.toml"], p["truth-sm.json"]
    P, PR = p["params"], p["ur5-params"]
    out = lambda n: os.path.join(d, "o", n)     # noqa: E731
    os.makedirs(os.path.join(d, "o"), exist_ok=True)
    gen = ["trace", "generate", "--method", "sm-distance"]

    # -- outputs ------------------------------------------------------------------------
    add = C.append
    n_own = [0]

    def own(src):
        """A private copy of an input (a case that may destroy it harms no other)."""
        n_own[0] += 1
        base = os.path.basename(src)
        dst = os.path.join(d, f"own{n_own[0]}-{base}")
        shutil.copy(src, dst)
        OWN[dst] = src
        return dst

    T0, R0, TR0 = T, R, TR
    T, R, TR, PR = own(T0), own(R0), own(TR0), own(PR)
    CSV, URDF, SIMCFG = own(p["ur5.csv"]), own(p["m10.urdf"]), own(p["sim-sm.toml"])
    add(Case("out-batch-out-is-trace", ["batch", T, "--out", T], inputs=[T]))
    link = os.path.join(d, "o", "link-to-trace.jsonl")
    os.symlink(T, link)
    add(Case("out-batch-out-symlink-to-trace", ["batch", T, "--out", link], inputs=[T]))
    add(Case("out-batch-report-is-trace", ["batch", T, "--out", out("a.json"), "--report", T],
             inputs=[T], absent=[out("a.json")]))
    add(Case("out-batch-devnull", ["batch", T, "--out", p["dev-null"]], inputs=[T],
             nodes=[p["dev-null"]]))
    add(Case("out-batch-devfull", ["batch", T, "--out", p["dev-full"]], inputs=[T],
             nodes=[p["dev-full"]]))
    add(Case("out-batch-fifo", ["batch", T, "--out", p["fifo"]], inputs=[T], nodes=[p["fifo"]]))
    add(Case("out-batch-report-devnull", ["batch", T, "--out", out("b.json"), "--report",
                                          p["dev-null"]], nodes=[p["dev-null"]],
             absent=[out("b.json")]))
    add(Case("out-batch-empty", ["batch", T, "--out", ""], inputs=[T]))
    add(Case("out-batch-empty-report", ["batch", T, "--out", out("c.json"), "--report", ""],
             expect="either"))
    add(Case("out-batch-folder", ["batch", T, "--out", p["folder"]]))
    add(Case("out-batch-missing-folder", ["batch", T, "--out", out("nope/p.json")]))
    add(Case("out-batch-same-twice", ["batch", T, "--out", out("d.json"), "--report",
                                      out("d.json")], absent=[out("d.json")]))
    add(Case("out-batch-out-is-params-ok", ["batch", T, "--out", out("e.json")], expect="ok"))
    add(Case("out-gen-out-is-truth", gen + ["--truth", TR, "--out", TR], inputs=[TR]))
    add(Case("out-gen-robot-out-is-robot", ["trace", "generate", "--robot", R, "--method",
                                            "sm-position", "--out", R], inputs=[R]))
    rt = os.path.join(d, "ur5-truth.json")
    add(Case("out-gen-robot-out-is-missing-truth", ["trace", "generate", "--robot", R,
                                                    "--method", "sm-position", "--truth", rt,
                                                    "--out", rt], inputs=[R]))
    add(Case("out-gen-devnull", gen + ["--out", p["dev-null"]], nodes=[p["dev-null"]]))
    add(Case("out-gen-robot-devnull", ["trace", "generate", "--robot", R, "--method",
                                       "sm-position", "--out", p["dev-null"]],
             nodes=[p["dev-null"]]))
    add(Case("out-gen-urdf-out-is-urdf", ["trace", "generate", "--robot", URDF,
                                          "--base-link", "base_link", "--tip-link", "flange",
                                          "--method", "sm-markers", "--out", URDF],
             inputs=[URDF]))
    add(Case("out-gen-empty", gen + ["--out", ""]))
    add(Case("out-gen-folder", gen + ["--out", p["folder"]]))
    add(Case("out-gen-fifo", gen + ["--out", p["fifo"]], nodes=[p["fifo"]]))
    add(Case("out-import-out-is-csv", ["trace", "import", CSV, "--robot", R,
                                       "--method", "sm-position", "--out", CSV],
             inputs=[CSV, R]))
    add(Case("out-import-out-is-robot", ["trace", "import", CSV, "--robot", R,
                                         "--method", "sm-position", "--out", R],
             inputs=[CSV, R]))
    add(Case("out-import-devnull", ["trace", "import", CSV, "--robot", R,
                                    "--method", "sm-position", "--out", p["dev-null"]],
             nodes=[p["dev-null"]]))
    add(Case("out-import-ok", ["trace", "import", CSV, "--robot", R, "--method",
                               "sm-position", "--out", out("imp.jsonl")], expect="ok"))
    add(Case("out-export-urdf-is-params", ["params", "export", PR, "--urdf", PR], inputs=[PR]))
    add(Case("out-export-robot-is-params", ["params", "export", PR, "--robot-file", PR],
             inputs=[PR]))
    add(Case("out-export-both-same", ["params", "export", PR, "--urdf", out("x.out"),
                                      "--robot-file", out("x.out")], absent=[out("x.out")]))
    add(Case("out-export-half", ["params", "export", PR, "--urdf", out("half.urdf"),
                                 "--robot-file", out("nope/b.toml")],
             absent=[out("half.urdf")]))
    add(Case("out-export-half-rev", ["params", "export", PR, "--urdf", out("nope/a.urdf"),
                                     "--robot-file", out("half.toml")],
             absent=[out("half.toml")]))
    add(Case("out-export-devnull", ["params", "export", PR, "--urdf", p["dev-null"]],
             nodes=[p["dev-null"]]))
    add(Case("out-export-robot-is-robot", ["params", "export", PR, "--robot-file", R],
             expect="either"))
    add(Case("out-export-ok", ["params", "export", PR, "--urdf", out("ok.urdf"),
                               "--robot-file", out("ok.toml")], expect="ok"))
    add(Case("out-simulate-endpoints-is-truth", ["simulate", "--robot", "agebot-sm", "--truth",
                                                 TR, "--endpoints", TR], inputs=[TR]))
    add(Case("out-simulate-endpoints-is-config", ["simulate", "--robot", "agebot-sm",
                                                  "--config", SIMCFG,
                                                  "--endpoints", SIMCFG],
             inputs=[SIMCFG]))
    add(Case("out-simulate-endpoints-devnull", ["simulate", "--robot", "agebot-sm",
                                                "--endpoints", p["dev-null"]],
             nodes=[p["dev-null"]]))
    add(Case("out-simulate-endpoints-folder", ["simulate", "--robot", "agebot-sm",
                                               "--endpoints", p["folder"]]))
    add(Case("out-run-out-is-robot", ["run", "--simulate", "--robot", R, "--truth", TR,
                                      "--method", "sm-position", "--out", R], inputs=[R]))
    add(Case("out-run-out-is-truth", ["run", "--simulate", "--robot", "agebot-sm", "--truth",
                                      TR, "--method", "sm-distance", "--out", TR],
             inputs=[TR]))
    add(Case("out-run-out-devnull", ["run", "--simulate", "--robot", "agebot-sm", "--method",
                                     "sm-distance", "--out", p["dev-null"]],
             nodes=[p["dev-null"]]))
    add(Case("out-run-out-empty", ["run", "--simulate", "--robot", "agebot-sm", "--method",
                                   "sm-distance", "--out", ""]))
    add(Case("out-study-out-is-file", ["study", "--method", "sm-distance", "--robots", "1",
                                       "--out", T], inputs=[T]))
    add(Case("out-study-out-devnull", ["study", "--method", "sm-distance", "--robots", "1",
                                       "--out", p["dev-null"]], nodes=[p["dev-null"]]))
    add(Case("out-study-out-empty", ["study", "--method", "sm-distance", "--robots", "1",
                                     "--out", ""]))
    sfold = os.path.join(d, "study-summary-dev")
    os.mkdir(sfold)
    os.mknod(os.path.join(sfold, "summary.json"), 0o666 | stat.S_IFCHR, os.makedev(1, 3)) \
        if os.geteuid() == 0 else os.mkfifo(os.path.join(sfold, "summary.json"))
    add(Case("out-study-summary-is-device", ["study", "--method", "sm-distance", "--robots",
                                             "1", "--out", sfold],
             nodes=[os.path.join(sfold, "summary.json")], timeout=60))

    T, R, TR, PR = T0, R0, TR0, p["ur5-params"]

    # -- hangs --------------------------------------------------------------------------
    hung = station_variant(p, d, "hung.toml", lambda t: t.replace(
        'host = "@endpoints"\nport = "@endpoints"\nnodes',
        f'host = "127.0.0.1"\nport = {hung_port}\nnodes', 1).replace(
        'port = "@endpoints"\nbaudrate', f'port = "socket://127.0.0.1:{dead_port}"\nbaudrate'
    ).replace('host = "@endpoints"\nport = "@endpoints"',
              f'host = "127.0.0.1"\nport = {dead_port}'))
    dead = station_variant(p, d, "dead.toml", lambda t: t.replace(
        'host = "@endpoints"\nport = "@endpoints"\nnodes',
        f'host = "127.0.0.1"\nport = {dead_port}\nnodes', 1).split("[inclinometer]")[0]
        + t[t.index("[snapshot]"):])
    add(Case("hang-devices-check-hung-can", ["devices", "check", "--config", hung, "--seconds",
                                             "0.5"], inputs=[hung]))
    add(Case("hang-run-hung-can", ["run", "--config", hung, "--robot", "agebot-sm", "--method",
                                   "sm-distance-tilt", "--out", out("hung-run")],
             inputs=[hung]))
    add(Case("hang-devices-check-dead-can", ["devices", "check", "--config", dead,
                                             "--seconds", "0.5"]))
    for v in ("nan", "inf", "-1", "1e308"):
        add(Case(f"hang-devices-check-seconds-{v}", ["devices", "check", "--config", dead,
                                                      "--seconds", v]))
    for v in ("-1", "0", "-100"):
        add(Case(f"hang-study-workers-{v}", ["study", "--method", "sm-distance", "--robots", "1",
                                             "--workers", v, "--out", out(f"st-w{v}")]))
    for key, val in (("sdo_timeout", "1e308"), ("move_timeout", "1e308"),
                     ("heartbeat_timeout", "1e308")):
        cfg = station_variant(p, d, f"to-{key}.toml",
                              lambda t, k=key, v=val: t.replace(f"{k} = ", f"{k} = {v}\n#", 1))
        add(Case(f"hang-config-{key}-huge", ["devices", "check", "--config", cfg, "--seconds",
                                             "0.5"]))
    add(Case("hang-study-robots-zero", ["study", "--method", "sm-distance", "--robots", "0",
                                        "--out", out("st-r0")]))

    # -- silently wrong -----------------------------------------------------------------
    add(Case("wrong-gen-robot-pm-sm-method", ["trace", "generate", "--robot", "agebot-pm",
                                              "--method", "sm-distance", "--out",
                                              out("w1.jsonl")], absent=[out("w1.jsonl")]))
    add(Case("wrong-gen-robot-sm-pm-method", ["trace", "generate", "--robot", "agebot-sm",
                                              "--method", "pm-fk", "--out", out("w2.jsonl")],
             absent=[out("w2.jsonl")]))
    add(Case("wrong-gen-robot-sm-ok", ["trace", "generate", "--robot", "agebot-sm",
                                       "--method", "sm-distance", "--out", out("w3.jsonl")],
             expect="ok"))
    add(Case("wrong-gen-robot-file-pm-method", ["trace", "generate", "--robot", R, "--method",
                                                "pm-fk", "--out", out("w4.jsonl")]))
    add(Case("wrong-gen-truth-pm-method-sm", gen + ["--truth", p["truth-pm.json"], "--out",
                                                    out("w5.jsonl")]))
    verify_edits = {
        "L2-negative": lambda doc: doc["parameters"]["L2"].update(value=-5.0),
        "L2-1e308": lambda doc: doc["parameters"]["L2"].update(value=1e308),
        "k1-zero": lambda doc: doc["parameters"]["k1"].update(value=0.0),
        "k2-negative-huge": lambda doc: doc["parameters"]["k2"].update(value=-1e6),
        "quality-failed": lambda doc: doc["fit"]["quality"].update(passed=False),
        "quality-failed-accepted-false": lambda doc: doc["fit"]["quality"].update(
            passed=False, accepted=False),
        "not-converged": lambda doc: doc["fit"].update(converged=False),
        "std-nan-text": lambda doc: json.dumps(doc).replace(
            '"std":', '"std": NaN, "x":', 1),
        "duplicate-value": lambda doc: json.dumps(doc).replace(
            '"value": ', '"value": -5.0, "value": ', 1),
        "value-1e400": lambda doc: json.dumps(doc).replace('"value": ', '"value": 1e400, "v": ',
                                                           1),
        "deep-nesting": lambda doc: json.dumps(doc)[:-1] + ', "x": ' + "[" * 100000
        + "]" * 100000 + "}",
        "theta0-huge": lambda doc: doc["parameters"]["theta0"].update(value=1e12),
    }
    for k, e in verify_edits.items():
        f = params_variant(p, d, f"v-{k}.json", e)
        add(Case(f"wrong-verify-{k}", ["params", "verify", f], inputs=[f]))
    add(Case("wrong-verify-ok", ["params", "verify", P], expect="ok", inputs=[P]))
    f = params_variant(p, d, "v-accepted.json",
                       lambda doc: doc["fit"]["quality"].update(passed=False, accepted=True))
    add(Case("wrong-verify-accepted-poor-fit", ["params", "verify", f], expect="either"))
    for k, e in {"d1-negative-huge": lambda doc: doc["parameters"]["d1"].update(value=1e308),
                 "k1-zero": lambda doc: doc["parameters"]["k1"].update(value=0.0)}.items():
        f = params_variant(p, d, f"vr-{k}.json", e, source="ur5-params")
        add(Case(f"wrong-verify-robotfile-{k}", ["params", "verify", f], inputs=[f]))
        add(Case(f"wrong-export-robotfile-{k}", ["params", "export", f, "--robot-file",
                                                  out(f"vr-{k}.toml")], inputs=[f]))

    # -- tracebacks: numbers at the edge ------------------------------------------------
    for v in ("nan", "inf", "-1", "0", "-inf", "1e400"):
        add(Case(f"tb-gen-noise-distance-{v}", gen + ["--noise", f"distance={v}", "--out",
                                                      out(f"n{v}.jsonl")]))
    add(Case("tb-gen-noise-unknown-channel", gen + ["--noise", "bogus=1e-4", "--out",
                                                    out("nb.jsonl")]))
    add(Case("tb-gen-noise-other-method-channel", gen + ["--noise", "tilt=1e-4", "--out",
                                                         out("nt.jsonl")], expect="either"))
    add(Case("tb-gen-noise-no-eq", gen + ["--noise", "distance", "--out", out("ne.jsonl")]))
    for v in ("nan", "-1", "bogus"):
        add(Case(f"tb-gen-robot-noise-{v}", ["trace", "generate", "--robot", R, "--method",
                                             "sm-position", "--noise", f"position={v}",
                                             "--out", out(f"rn{v}.jsonl")]))
    add(Case("tb-gen-robot-noise-zero", ["trace", "generate", "--robot", R, "--method",
                                         "sm-position", "--noise", "position=0", "--out",
                                         out("rn0.jsonl")]))
    for a in (["--seed", "-1"], ["--count", "-5"], ["--count", "0"], ["--count", "1"],
              ["--seed", "99999999999999999999999"], ["--count", "100000000000"]):
        add(Case("tb-gen-" + "".join(a).replace("--", ""), gen + a + ["--out",
                                                                    out("g.jsonl")],
                 expect="either" if a[1] in ("1", "99999999999999999999999") else "refuse"))
    for a in (["--seed", "-1"], ["--count", "-5"], ["--count", "0"]):
        add(Case("tb-gen-robot-" + "".join(a).replace("--", ""),
                 ["trace", "generate", "--robot", R, "--method", "sm-position", *a, "--out",
                  out("g2.jsonl")]))
    add(Case("tb-gen-components-bad", ["trace", "generate", "--method", "pm-fk", "--components",
                                       "alpha,delta", "--out", out("c.jsonl")]))
    add(Case("tb-gen-components-dup", ["trace", "generate", "--method", "pm-fk",
                                       "--components", "alpha,alpha", "--out",
                                       out("c2.jsonl")]))
    add(Case("tb-gen-components-empty", ["trace", "generate", "--method", "pm-fk",
                                         "--components", ",", "--out", out("c3.jsonl")]))
    add(Case("tb-gen-components-not-pm-fk", gen + ["--components", "alpha", "--out",
                                                   out("c4.jsonl")]))
    add(Case("tb-gen-known-bogus", gen + ["--known", "bogus", "--out", out("k.jsonl")]))
    add(Case("tb-gen-truth-missing", gen + ["--truth", out("nope.json"), "--out",
                                            out("tm.jsonl")]))
    add(Case("tb-gen-truth-other-robot", gen + ["--truth", p["truth-pm.json"], "--out",
                                                out("to.jsonl")]))
    tnan = truth_variant(p, d, "truth-nan.json", lambda doc: doc["noise"].update(distance=-1))
    add(Case("tb-gen-truth-negative-noise", gen + ["--truth", tnan, "--out", out("tn.jsonl")]))
    tdeep = os.path.join(d, "truth-deep.json")
    with open(tdeep, "w") as f:
        f.write('{"robot": "agebot-sm", "x": ' + "[" * 100000 + "]" * 100000 + "}")
    add(Case("tb-gen-truth-deep", gen + ["--truth", tdeep, "--out", out("td.jsonl")]))
    sim = ["run", "--simulate", "--robot", "agebot-sm", "--method", "sm-distance-tilt"]
    for a in (["--count", "-5"], ["--count", "0"], ["--seed", "-1"], ["--sim-seed", "-1"],
              ["--sim-seed", "99999999999999999999999"], ["--method", "bogus"],
              ["--truth", p["truth-pm.json"]], ["--nominal", "k1=nan"],
              ["--nominal", "bogus=1"], ["--target-std", "nan"], ["--target-std", "-1"],
              ["--nominal", "k1=inf"]):
        add(Case("tb-run-" + "".join(a).replace("--", "").replace(os.sep, "_")[:40],
                 sim + a + ["--out", out("run-" + a[0].strip("-") + a[1][-6:].replace("/", ""))]))
    add(Case("tb-run-robot-missing", ["run", "--simulate", "--robot", out("nope.toml"),
                                      "--method", "sm-position", "--out", out("r-miss")]))
    add(Case("tb-run-robot-file-no-truth", ["run", "--simulate", "--robot", R, "--method",
                                            "sm-position", "--out", out("r-nt")]))
    add(Case("tb-run-robot-file-truth-of-agebot", ["run", "--simulate", "--robot", R,
                                                   "--truth", TR, "--method", "sm-position",
                                                   "--out", out("r-ta")]))
    add(Case("tb-run-no-config", ["run", "--robot", "agebot-sm", "--method", "sm-distance",
                                  "--out", out("r-nc")]))
    for a in (["--seed", "-1"], ["--truth", p["truth-pm.json"]], ["--robot", "bogus"],
              ["--truth", out("nope.json")]):
        add(Case("tb-simulate-" + "".join(a).replace("--", "").replace(os.sep, "_")[-30:],
                 ["simulate", "--robot", "agebot-sm", *a] if a[0] != "--robot"
                 else ["simulate", *a]))
    st = ["study", "--method", "sm-distance", "--robots", "1"]
    for a in (["--seed", "-1"], ["--scheduler", "foo"], ["--scheduler", "tcp://127.0.0.1:1"],
              ["--count", "-1"], ["--count", "0"], ["--noise", "distance=nan"],
              ["--noise", "distance=0"], ["--noise", "bogus=1"], ["--gear", "nan"],
              ["--gear", "1.5"], ["--method", "bogus"], ["--design", "foo"],
              ["--robot", "agebot-pm"], ["--length", "-1"], ["--offset", "inf"]):
        add(Case("tb-study-" + "".join(a).replace("--", "").replace("/", "_")[:40],
                 st + a + ["--out", out("st" + a[0].strip("-") + a[1][-5:].replace("/", ""))]))
    for a in (["--max-iter", "-5"], ["--max-iter", "0"], ["--method", "bogus"],
              ["--method", "pm-fk"], ["--exclude", "x", "--exclude-reason", "r"],
              ["--exclude", "99999", "--exclude-reason", "r"], ["--hold", "zz*"],
              ["--exclude", "1"]):
        add(Case("tb-batch-" + "".join(a).replace("--", "")[:30],
                 ["batch", T, *a, "--out", out("b-" + a[1][:5] + ".json")]))
    add(Case("tb-batch-missing-trace", ["batch", out("nope.jsonl"), "--out", out("bm.json")]))
    add(Case("tb-batch-trace-is-folder", ["batch", p["folder"], "--out", out("bf.json")]))
    add(Case("tb-batch-trace-is-devnull", ["batch", p["dev-null"], "--out", out("bn.json")]))
    add(Case("tb-verify-missing", ["params", "verify", out("nope.json")]))
    add(Case("tb-verify-folder", ["params", "verify", p["folder"]]))
    add(Case("tb-verify-trace", ["params", "verify", T], inputs=[T]))
    add(Case("tb-export-no-output", ["params", "export", PR]))
    add(Case("tb-export-agebot", ["params", "export", P, "--urdf", out("ag.urdf")]))

    # -- robot files --------------------------------------------------------------------
    def rv(name, edit):
        return robot_variant(p, d, name, edit)
    lim = 'limits = [-3.141592653589793, 3.141592653589793]'
    text = open(R).read()
    has_lim = lim in text
    variants = {
        "limits-1e308": lambda t: t.replace(lim, "limits = [-1e308, 1e308]") if has_lim
        else t.replace("limits = [", "limits = [-1e308, 1e308]\n#", 1),
        "limits-inf": lambda t: t.replace("limits = [", "limits = [-inf, inf]\n#", 1),
        "limits-nan": lambda t: t.replace("limits = [", "limits = [nan, 1.0]\n#", 1),
        "k-1e308": lambda t: t.replace("k = ", "k = 1e308\n#", 1),
        "k-tiny": lambda t: t.replace("k = ", "k = 1e-320\n#", 1),
        "a-1e308": lambda t: t.replace("a = ", "a = 1e308\n#", 1),
        "d-nan": lambda t: t.replace("\nd = ", "\nd = nan\n#", 1),
        "nested-100000": lambda t: t + "\nx = " + "[" * 100000 + "]" * 100000 + "\n",
        "bom": lambda t: b"\xef\xbb\xbf" + t.encode(),
        "utf16": lambda t: t.encode("utf-16"),
        "latin1": lambda t: t.replace('name = "', 'name = "\xe9', 1).encode("latin-1"),
        "empty": lambda t: "",
        "binary": lambda t: bytes(range(256)),
        "name-newline": lambda t: t.replace('name = "', 'name = "a\\nb', 1),
        "name-quote": lambda t: t.replace('name = "', 'name = "a\\"b', 1),
        "name-control": lambda t: t.replace('name = "', 'name = "a\\u0007b', 1),
        "no-joints": lambda t: t.split("[[joint]]")[0],
        "limits-reversed": lambda t: t.replace("limits = [", "limits = [5.0, -5.0]\n#", 1),
        "fixed-unknown": lambda t: t.replace('name = "', 'fixed = ["zz"]\nname = "', 1),
        "version-2": lambda t: t.replace("version = 1", "version = 2", 1),
        "k-negative": lambda t: t.replace("k = ", "k = -1.0\n#", 1),
        "huge-int": lambda t: t.replace("k = ", "k = 99999999999999999999\n#", 1),
    }
    for name, e in variants.items():
        f = rv(f"r-{name}.toml", e)
        exp = "either" if name in ("bom", "name-quote", "k-negative", "k-tiny") else "refuse"
        if name == "bom":
            exp = "ok"
        add(Case(f"robot-gen-{name}", ["trace", "generate", "--robot", f, "--method",
                                       "sm-position", "--out", out(f"rg-{name}.jsonl")],
                 expect=exp, inputs=[f]))
    for name in ("limits-1e308", "k-1e308", "nested-100000", "bom", "name-newline"):
        f = os.path.join(d, f"r-{name}.toml")
        add(Case(f"robot-sim-{name}", ["run", "--simulate", "--robot", f, "--method",
                                       "sm-position", "--out", out(f"rs-{name}")],
                 expect="refuse" if name != "bom" else "either", inputs=[f],
                 timeout=HANG_S if name != "bom" else 120))
    # the newline name: generate, calibrate and export a robot file that must read back
    nl = os.path.join(d, "r-name-newline.toml")
    add(Case("robot-import-nested", ["trace", "import", p["ur5.csv"], "--robot",
                                     os.path.join(d, "r-nested-100000.toml"), "--method",
                                     "sm-position", "--out", out("rin.jsonl")]))
    add(Case("robot-import-bom", ["trace", "import", p["ur5.csv"], "--robot",
                                  os.path.join(d, "r-bom.toml"), "--method", "sm-position",
                                  "--out", out("rib.jsonl")], expect="ok"))
    del nl

    # -- station configs ----------------------------------------------------------------
    sv = {
        "nested": lambda t: t + "\nx = " + "[" * 100000 + "]" * 100000 + "\n",
        "bom": lambda t: b"\xef\xbb\xbf" + t.encode(),
        "sdo-nan": lambda t: t.replace("sdo_timeout = 0.5", "sdo_timeout = nan"),
        "sdo-zero": lambda t: t.replace("sdo_timeout = 0.5", "sdo_timeout = 0.0"),
        "node-0": lambda t: t.replace("nodes = [1, 2, 3, 4]", "nodes = [0, 2, 3, 4]"),
        "resolution-0": lambda t: t.replace("increments_per_unit = [131072,",
                                            "increments_per_unit = [0,"),
        "samples-0": lambda t: t.replace("samples = 5", "samples = 0"),
        "samples-huge": lambda t: t.replace("samples = 5", "samples = 100000000000"),
        "unknown-key": lambda t: t.replace("[snapshot]", "[snapshot]\nbogus = 1"),
        "robot-unknown": lambda t: t.replace('robot = "agebot-sm"', 'robot = "r2d2"'),
        "robot-file-missing": lambda t: t.replace('robot = "agebot-sm"',
                                                  'robot_file = "nope.toml"'),
        "robot-file-self": lambda t: t.replace('robot = "agebot-sm"',
                                               'robot_file = "st-robot-file-self.toml"'),
        "envelope-nan": lambda t: t.replace("qm_min = [-85.0,", "qm_min = [nan,"),
        "tolerance-inf": lambda t: t.replace("distance = 0.05", "distance = inf"),
        "binary": lambda t: bytes(range(256)) * 3,
    }
    for name, e in sv.items():
        f = station_variant(p, d, f"st-{name}.toml", e)
        add(Case(f"station-check-{name}", ["devices", "check", "--config", f, "--seconds",
                                           "0.3"], inputs=[f],
                 expect="refuse"))
        if name in ("nested", "sdo-nan", "robot-file-self", "binary"):
            add(Case(f"station-run-{name}", ["run", "--simulate", "--robot", "agebot-sm",
                                             "--config", f, "--method", "sm-distance-tilt",
                                             "--out", out(f"sr-{name}")], inputs=[f]))
    # parameter files
    for name, e in {"value-1e400": verify_edits["value-1e400"],
                    "duplicate": verify_edits["duplicate-value"]}.items():
        f = params_variant(p, d, f"e-{name}.json", e, source="ur5-params")
        add(Case(f"params-export-{name}", ["params", "export", f, "--robot-file",
                                           out(f"e-{name}.toml")], inputs=[f]))
    return C


# -- data: a robot file's and a URDF robot's measurements with a user's mistakes ----------
#
# Each case is ``trace import`` then (if it exits 0) ``batch``: a unit, sign, mirror, joint
# column or map mistake must be refused (at import or by the gate) with one ``error:``
# line; correct data (also with one gross reading, or a robot file one length of which is
# 10 % off the truth) must be accepted *and right*: the parameter file's identifiable
# parameters that absorb no held one within DATA_Z of their reported std of the truth,
# and the calibrated model's prediction within DATA_PRED of the truth's (random poses in
# the middle 80 % of the limits; the draw-wire methods, which do not see the base frame,
# by distances between tool origins: point_to_point_rms). A URDF robot's answer is judged
# by the points it predicts in the instrument's frame at the truth's poses and at fresh
# ones. An accepted answer that fails these is counted "wrong" (a confident wrong
# answer), an accepted answer of data to be refused too.

DATA_TIMEOUT = 240.0     # s per command of a data case (a fit on 2 shared cores)
DATA_Z = 5.0             # |calibrated - truth| / std of an honest identifiable parameter
DATA_PRED = 5.0          # prediction RMS within this many times the reading noise
SERIAL_NOISE = {"position": 1e-5, "pose": 1e-5, "distance": 1e-5, "tilt": 1e-4}
SERIAL_COLS = {"position": ("x", "y", "z"), "pose": ("x", "y", "z", "roll", "pitch", "yaw"),
               "distance": ("distance",), "tilt": ("tilt_roll", "tilt_pitch")}
LENGTH_COLS = ("x", "y", "z", "distance")
ANGLE_COLS = ("roll", "pitch", "yaw", "tilt_roll", "tilt_pitch")
MOUNT = (0.01, -0.02)
URDF_NOISE = 3e-5


def _here_on_path():
    """The sweep's own tools (truths, readings, checks) come from this checkout, whatever
    ``--root`` runs."""
    if HERE not in sys.path:
        sys.path.insert(0, HERE)


def write_rows(path, head, rows):
    def cell(v):
        return "" if v is None else v if isinstance(v, str) else repr(float(v))
    with open(path, "w") as f:
        f.write(",".join(head) + "\n")
        f.writelines(",".join(cell(r.get(c)) for c in head) + "\n" for r in rows)


class SerialData:
    """A drawn robot of a robot file and its readings by one method: rows of a CSV
    (``qm1 ..``, the method's columns, ``use``) that variants change."""

    def __init__(self, robot_path, method, *, seed, edit_truth=None):
        _here_on_path()
        import numpy as np

        from calibration.robots import get_robot
        from drivers.robot_file import load_robot_file
        from drivers.sim.serial_robot import draw_serial_truth
        from station.simulation.tracegen_serial import default_count, generate

        self.path, self.method = robot_path, method
        self.robot = get_robot(load_robot_file(robot_path))
        xi = draw_serial_truth(robot_path, np.random.default_rng(seed)).xi()
        if edit_truth:
            edit_truth(self.robot, xi)
        self.xi = xi
        fit = default_count(self.robot, method) + 4
        held = max(8, fit // 4)
        noise = {k: v for k, v in SERIAL_NOISE.items()}
        _h, ref, poses = generate(self.robot, method, xi, noise=noise, seed=seed,
                                  count=fit + held, mount=MOUNT)
        n = self.robot.n_actuators
        self.qcols = [f"qm{i + 1}" for i in range(n)]
        self.mcols = [c for ch, cols in SERIAL_COLS.items() if ch in poses[0] for c in cols]
        self.noise = noise["tilt" if method == "sm-distance-tilt" else
                           "distance" if method == "sm-distance" else "position"]
        rows = []
        if ref is not None:
            rows.append({**dict(zip(self.qcols, ref["qm"])), "use": "reference"})
        for k, p in enumerate(poses):
            r = dict(zip(self.qcols, p["qm"]))
            for ch, cols in SERIAL_COLS.items():
                if ch in p:
                    v = p[ch] if isinstance(p[ch], list) else [p[ch]]
                    r.update(zip(cols, v))
            r["use"] = "fit" if k < fit else "validation"
            rows.append(r)
        self.rows = rows
        self.head = self.qcols + self.mcols + ["use"]

    def write(self, path, transform=None, *, validation=True):
        rows = [dict(r) for r in self.rows]
        if not validation:
            rows = [r for r in rows if r["use"] != "validation"]
        if transform is not None:
            rows = transform(rows, self)
        write_rows(path, self.head, rows)
        return path

    def check(self, params_path, stdout, outlier=None) -> tuple[str, str]:
        """``(problems, figures)``: problems '' if the parameter file is the truth's
        calibration, else what is wrong; figures what was measured."""
        import numpy as np

        from station.planning.serial_plan import point_to_point_rms

        try:
            doc = json.load(open(params_path))
            P = doc["parameters"]
            x = np.array([P[n]["value"] for n in self.robot.param_names], dtype=float)
        except (OSError, ValueError, KeyError) as e:
            return f"no parameter file to judge: {e}", ""
        truth = dict(zip(self.robot.param_names, self.xi))
        truth.update(mount_x=MOUNT[0], mount_y=MOUNT[1])
        z = [(n, (p["value"] - truth[n]) / p["std"]) for n, p in P.items()
             if p.get("identifiable") and not p.get("absorbs") and n in truth and p.get("std")]
        worst = max(z, key=lambda t: abs(t[1])) if z else ("none", 0.0)
        problems = []
        if abs(worst[1]) > DATA_Z:
            problems.append(f"{worst[0]} {worst[1]:+.3g} std from the truth")
        if self.method in ("sm-position", "sm-full-pose"):
            rng = np.random.default_rng(11)
            lo, hi = self.robot.limits[:, 0], self.robot.limits[:, 1]
            q = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), size=(400, len(lo)))
            d = (self.robot.frames(q, x)[:, :3, 3] - self.robot.frames(q, self.xi)[:, :3, 3])
            pred = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
            tol = DATA_PRED * SERIAL_NOISE["position"]
        else:
            pred = point_to_point_rms(self.robot, x, self.xi, pairs=300)
            tol = DATA_PRED * SERIAL_NOISE["distance"]
        if pred > tol:
            problems.append(f"predicts the tool {pred * 1e3:.3g} mm RMS off the truth")
        if outlier is not None and not any(f"pose {outlier} " in ln for ln in stdout.splitlines()
                                           if "outliers:" in ln):
            problems.append(f"the gross reading of pose {outlier} is not named an outlier")
        figures = (f"worst |z| {abs(worst[1]):.3g} ({worst[0]}) of {len(z)} identifiable on "
                   f"their own; prediction {pred * 1e3:.3g} mm RMS from the truth")
        return "; ".join(problems), figures


def _scale(cols, f):
    def t(rows, _data):
        for r in rows:
            for c in cols:
                if isinstance(r.get(c), float):
                    r[c] *= f
        return rows
    return t


def _flip(col):
    return _scale([col], -1.0)


def _swap(a, b):
    def t(rows, _data):
        for r in rows:
            r[a], r[b] = r.get(b), r.get(a)
        return rows
    return t


def _offset_joint(col, delta):
    """A joint column read ``delta`` off; rows then beyond the limits are left out (so
    the import's limit check does not do the sweep's work)."""
    def t(rows, data):
        i = data.qcols.index(col)
        lo, hi = data.robot.limits[i]
        out = []
        for r in rows:
            r[col] += delta
            if lo <= r[col] <= hi:
                out.append(r)
        return out
    return t


def _gross(pose, col, delta):
    def t(rows, _data):
        fit = [r for r in rows if r["use"] == "fit"]
        fit[pose][col] += delta
        return rows
    return t


def _then(*ts):
    def t(rows, data):
        for f in ts:
            rows = f(rows, data)
        return rows
    return t


def serial_data_cases(root: str, d: str) -> list[Case]:
    """Robot-file data: the fixtures' three robots (Hayati, SCARA with a prismatic quill,
    DH), drawn truths (+-3 mm, +-5 mrad), readings by sm-position, sm-full-pose,
    sm-distance and sm-distance-tilt written as ``trace import``'s CSV."""
    fx = os.path.join(root, "fixtures", "robots")
    mm = 1000.0
    deg = 180.0 / 3.141592653589793
    C = []
    folder = os.path.join(d, "data")
    os.makedirs(folder, exist_ok=True)
    for rname, seed in (("ur5-like-hayati", 21), ("scara-like", 22), ("ur5-like-dh", 23)):
        rpath = os.path.join(fx, f"{rname}.toml")
        data = {m: SerialData(rpath, m, seed=seed) for m in
                ("sm-position", "sm-full-pose", "sm-distance", "sm-distance-tilt")}

        def ten(robot, xi):
            """One length of the truth 10 % off the robot file's."""
            j = robot.index("a2")
            xi[j] = 1.1 * robot.nominal[j]
        long = {m: SerialData(rpath, m, seed=seed + 100, edit_truth=ten)
                for m in ("sm-position", "sm-distance-tilt")}
        gross = SerialData(rpath, "sm-position", seed=seed + 200)
        # (name, data, transform, extra import flags, expect, outlier pose, write kw)
        specs = [
            ("pos-ok", data["sm-position"], None, [], "ok", None, {}),
            ("pos-ok-mm", data["sm-position"], _scale(LENGTH_COLS, mm),
             ["--length-unit", "mm"], "ok", None, {}),
            ("pos-ok-sigma", data["sm-position"], None,
             ["--sigma", "x=1e-5", "--sigma", "y=1e-5", "--sigma", "z=1e-5"], "ok", None, {}),
            ("full-ok", data["sm-full-pose"], None, [], "ok", None, {}),
            ("full-ok-deg", data["sm-full-pose"], _scale(ANGLE_COLS, deg),
             ["--angle-unit", "deg"], "ok", None, {}),
            ("dist-ok", data["sm-distance"], None, [], "ok", None, {}),
            ("dtilt-ok", data["sm-distance-tilt"], None, [], "ok", None, {}),
            ("pos-length-10pc-off", long["sm-position"], None, [], "ok", None, {}),
            ("dtilt-length-10pc-off", long["sm-distance-tilt"], None, [], "ok", None, {}),
            ("pos-gross-reading", gross, _gross(7, "y", 0.005), [], "ok", 7, {}),
            ("pos-mm-as-m", data["sm-position"], _scale(LENGTH_COLS, mm), [], "refuse",
             None, {}),
            ("pos-mm-as-m-no-validation", data["sm-position"], _scale(LENGTH_COLS, mm), [],
             "refuse", None, {"validation": False}),
            ("pos-m-as-mm", data["sm-position"], None, ["--length-unit", "mm"], "refuse",
             None, {}),
            ("pos-m-as-mm-no-validation", data["sm-position"], None, ["--length-unit", "mm"],
             "refuse", None, {"validation": False}),
            ("full-deg-as-rad", data["sm-full-pose"], _scale(ANGLE_COLS, deg), [], "refuse",
             None, {}),
            ("full-rad-as-deg", data["sm-full-pose"], None, ["--angle-unit", "deg"],
             "refuse", None, {}),
            ("full-mm-as-m", data["sm-full-pose"], _scale(LENGTH_COLS, mm), [], "refuse",
             None, {}),
            ("dist-mm-as-m", data["sm-distance"], _scale(LENGTH_COLS, mm), [], "refuse",
             None, {}),
            ("dist-m-as-mm", data["sm-distance"], None, ["--length-unit", "mm"], "refuse",
             None, {}),
            ("dtilt-tilt-deg-as-rad", data["sm-distance-tilt"], _scale(ANGLE_COLS, deg), [],
             "refuse", None, {}),
            ("dtilt-tilt-rad-as-deg", data["sm-distance-tilt"], None, ["--angle-unit", "deg"],
             "refuse", None, {}),
            ("dtilt-dist-mm-as-m", data["sm-distance-tilt"], _scale(["distance"], mm), [],
             "refuse", None, {}),
            ("pos-x-flipped", data["sm-position"], _flip("x"), [], "refuse", None, {}),
            ("pos-z-flipped", data["sm-position"], _flip("z"), [], "refuse", None, {}),
            ("pos-x-y-swapped", data["sm-position"], _swap("x", "y"), [], "refuse", None, {}),
            ("full-x-flipped", data["sm-full-pose"], _flip("x"), [], "refuse", None, {}),
            ("dtilt-tilts-swapped", data["sm-distance-tilt"], _swap("tilt_roll", "tilt_pitch"),
             [], "refuse", None, {}),
            ("dtilt-roll-flipped", data["sm-distance-tilt"], _flip("tilt_roll"), [], "refuse",
             None, {}),
            ("pos-qm2-flipped", data["sm-position"], _flip("qm2"), [], "refuse", None, {}),
            ("pos-qm1-qm2-swapped", data["sm-position"], _swap("qm1", "qm2"), [], "refuse",
             None, {}),
            ("pos-qm2-plus-90deg", data["sm-position"], _offset_joint("qm2", 1.5707963267948966),
             [], "refuse", None, {}),
            ("dtilt-qm2-plus-90deg", data["sm-distance-tilt"],
             _offset_joint("qm2", 1.5707963267948966), [], "refuse", None, {}),
            # an instrument's scale is not observable (a robot whose every length is 2 %
            # larger reads the same): accepted, with the note that says so
            ("pos-scale-2pc", data["sm-position"], _scale(LENGTH_COLS, 1.02), [], "scale",
             None, {}),
        ]
        for name, sd, tf, flags, expect, outlier, kw in specs:
            tag = f"{rname}-{name}"
            csv = sd.write(os.path.join(folder, f"{tag}.csv"), tf, **kw)
            tr, pj = os.path.join(folder, f"{tag}.jsonl"), os.path.join(folder, f"{tag}.json")
            check = None
            if expect == "ok":
                check = (lambda so, sd=sd, pj=pj, o=outlier: sd.check(pj, so, outlier=o))
            if expect == "scale":
                expect, check = "ok", scale_noted
            C.append(Case(f"data-rf-{tag}", ["trace", "import", csv, "--robot", rpath,
                                             "--method", sd.method, "--out", tr, *flags],
                          expect=expect, inputs=[csv, rpath], timeout=DATA_TIMEOUT,
                          then=[["batch", tr, "--out", pj]], check=check))
    return C


def scale_noted(stdout: str) -> tuple[str, str]:
    """An instrument's scale error is not observable (every length 2 % larger reads the
    same): the right answer is the calibration with the note that says so."""
    ok = "the instrument's scale is not observed" in stdout
    return ("" if ok else "no note that the instrument's scale is not observed"), ""


class UrdfData:
    """A drawn m10ia-like arm measured by a tracker, as ``tracker_export`` writes it:
    ``joints`` (m, 6) rad (the URDF's), the FANUC columns, ``P`` (m, 3, 3) m."""

    def __init__(self, folder, seed, *, tilt=0.6):
        _here_on_path()
        import numpy as np

        from calibration.robots import get_robot
        from drivers.urdf_file import load_urdf
        from station.simulation import tracegen_urdf as tg

        self.urdf = os.path.join(HERE, "fixtures", "robots", "m10ia-like.urdf")
        self.robot = get_robot(load_urdf(self.urdf, "base_link", "tool0"))
        os.makedirs(folder, exist_ok=True)
        self.x, self.q, self.P = tg.tracker_export(folder, self.robot, seed, noise=URDF_NOISE,
                                                   tilt=tilt)
        self.map = os.path.join(folder, "map.toml")
        self.csv = os.path.join(folder, "meas.csv")
        n = self.robot.n_params
        self.xr, self.u = self.x[:n], self.x[n:].reshape(-1, 3)
        self.use = ["fit"] * 60 + ["validation"] * 20
        self.tg, self.np = tg, np

    def columns(self, unit="deg"):
        f = 180.0 / 3.141592653589793 if unit == "deg" else 1.0
        a = self.q * f
        return {"J1": a[:, 0], "J2": a[:, 1], "J3": a[:, 2] - a[:, 1], "J4": a[:, 3],
                "J5": a[:, 4], "J6": a[:, 5]}

    def write(self, path, *, unit="deg", length=1e-3, cols=None, P=None, style="m",
              use=True, extra=None, rows=None):
        c = self.columns(unit) if cols is None else cols
        if extra:
            c = {**c, **extra}
        P = self.P if P is None else P
        uses = self.np.array(self.use)
        if rows is not None:
            c = {k: v[rows] for k, v in c.items()}
            P, uses = P[rows], uses[rows]
        text = self.tg.write_csv(c, P, length_scale=length,
                                 use=list(uses) if use else None, style=style)
        with open(path, "w") as f:
            f.write(text)
        return path

    def inside(self, joints):
        """The rows whose URDF joint values ``joints`` (m, 6) rad lie within the limits."""
        lim = self.robot.limits
        return self.np.all((joints >= lim[:, 0]) & (joints <= lim[:, 1]), axis=1)

    def predicted(self, robot, x, u, q):
        np = self.np
        T = robot.frames(q, x)
        return T[:, None, :3, 3] + np.einsum("mij,kj->mki", T[:, :3, :3], u)

    def check(self, trace_path, params_path, stdout, outlier=None) -> tuple[str, str]:
        np = self.np
        from station.recording.trace import read_trace

        try:
            rob = read_trace(trace_path).robot_model()
            doc = json.load(open(params_path))
            Pp = doc["parameters"]
            x = np.array([Pp[n]["value"] for n in rob.param_names], dtype=float)
            u = np.array([Pp[f"marker{j + 1}_{a}"]["value"] for j in range(len(self.u))
                          for a in "xyz"]).reshape(-1, 3)
        except (OSError, ValueError, KeyError) as e:
            return f"no parameter file to judge: {e}", ""
        rng = np.random.default_rng(12)
        fresh = self.tg.draw_poses(self.robot, 300, rng)
        problems, figures = [], []
        for what, q in (("the measured poses", self.q), ("fresh poses", fresh)):
            try:
                d = self.predicted(rob, x, u, q) - self.predicted(self.robot, self.xr, self.u, q)
            except Exception as e:  # noqa: BLE001 - another chain: not this robot
                return f"the calibrated chain does not take the arm's joints: {e}", ""
            rms = float(np.sqrt(np.mean(np.sum(d ** 2, axis=2))))
            figures.append(f"points at {what} {rms * 1e3:.3g} mm RMS from the truth")
            if rms > DATA_PRED * URDF_NOISE:
                problems.append(f"points at {what} {rms * 1e3:.3g} mm RMS off the truth")
        if outlier is not None and not any(f"pose {outlier} " in ln
                                           for ln in stdout.splitlines() if "outliers:" in ln):
            problems.append(f"the gross reading of pose {outlier} is not named an outlier")
        return "; ".join(problems), ", ".join(figures)


NO_COUPLING_MAP = """format = "calstation-joint-map"
version = 1
""" + "".join(f'[[joint]]\nurdf = "joint_{i}"\ncolumn = "J{i}"\n' for i in range(1, 7))


def urdf_data_cases(root: str, d: str) -> list[Case]:
    """URDF data: drawn m10ia-like arms (FANUC columns in degrees, J3 from the
    horizontal, a tracker's mm, three reflectors, beams broken at random)."""
    C = []
    urdf = os.path.join(root, "fixtures", "robots", "m10ia-like.urdf")
    top = os.path.join(d, "udata")
    nocoup = os.path.join(d, "no-coupling-map.toml")
    with open(nocoup, "w") as f:
        f.write(NO_COUPLING_MAP)
    sets = {1: UrdfData(os.path.join(top, "s1"), 31), 2: UrdfData(os.path.join(top, "s2"), 32)}
    anyframe = UrdfData(os.path.join(top, "s3"), 33, tilt=None)

    def add(name, ud, csv, *, flags=(), expect="refuse", base="base_link", tip="tool0",
            jmap=None, outlier=None, units=("mm", "deg")):
        tr = os.path.join(top, f"{name}.jsonl")
        pj = os.path.join(top, f"{name}.json")
        argv = ["trace", "import", csv, "--robot", urdf, "--base-link", base, "--tip-link",
                tip, "--method", "sm-markers", "--out", tr]
        if units[0]:
            argv += ["--length-unit", units[0]]
        if units[1]:
            argv += ["--angle-unit", units[1]]
        argv += ["--joint-map", jmap or ud.map] if jmap != "" else []
        argv += list(flags)
        check = None
        if expect == "ok":
            check = (lambda so, ud=ud, tr=tr, pj=pj, o=outlier: ud.check(tr, pj, so, outlier=o))
        if expect == "scale":
            expect, check = "ok", scale_noted
        C.append(Case(f"data-urdf-{name}", argv, expect=expect, inputs=[csv, urdf],
                      timeout=DATA_TIMEOUT, then=[["batch", tr, "--out", pj]], check=check))

    for s, ud in sets.items():
        def w(n, ud=ud, s=s, **kw):
            return ud.write(os.path.join(top, f"s{s}-{n}.csv"), **kw)
        P = ud.P
        add(f"s{s}-ok", ud, ud.csv, expect="ok")
        add(f"s{s}-ok-m-rad", ud, w("m-rad", unit="rad", length=1.0), expect="ok",
            units=(None, None))
        add(f"s{s}-mm-as-m", ud, ud.csv, units=(None, "deg"))
        add(f"s{s}-m-as-mm", ud, w("m", length=1.0))
        add(f"s{s}-deg-as-rad", ud, ud.csv, units=("mm", None))
        add(f"s{s}-rad-as-deg", ud, w("rad", unit="rad"))
        Px = P.copy()
        Px[..., 0] *= -1
        add(f"s{s}-x-flipped", ud, w("xflip", P=Px))
        Pxy = P[..., [1, 0, 2]]
        add(f"s{s}-x-y-swapped", ud, w("xyswap", P=Pxy))
        c = ud.columns()
        add(f"s{s}-J4-J5-swapped", ud, w("j45", cols={**c, "J4": c["J5"], "J5": c["J4"]}))
        add(f"s{s}-J1-flipped", ud, w("j1flip", cols={**c, "J1": -c["J1"]}))
        add(f"s{s}-no-J2-J3-coupling", ud, ud.csv, jmap=nocoup)
        add(f"s{s}-J4-plus-90deg", ud, w("j4off", cols={**c, "J4": c["J4"] + 90.0}))
        # the same mistakes where every row stays within the limits (the rows beyond left
        # out, so that the import's limit check does not do the sweep's work)
        rad = ud.np.radians
        q = ud.q.copy()
        q[:, 3] += rad(90.0)
        add(f"s{s}-J4-plus-90deg-in-limits", ud, w("j4off-in", cols={**c, "J4": c["J4"] + 90.0},
                                                  rows=ud.inside(q)))
        q = ud.q.copy()
        q[:, 2] = rad(c["J3"])
        add(f"s{s}-no-J2-J3-coupling-in-limits", ud, w("nocoup-in", rows=ud.inside(q)),
            jmap=nocoup)
        q = ud.q.copy()
        q[:, 1], q[:, 2] = -ud.q[:, 1], ud.q[:, 2] - 2 * ud.q[:, 1]    # joint_3 = J2 + J3
        add(f"s{s}-J2-flipped-in-limits", ud, w("j2flip-in", cols={**c, "J2": -c["J2"]},
                                                rows=ud.inside(q)))
        Pg = P.copy()
        k = next(i for i in range(5, 60) if ud.np.all(ud.np.isfinite(P[i, 0])))
        Pg[k, 0, 1] += 0.005
        add(f"s{s}-gross-reading", ud, w("gross", P=Pg), expect="ok", outlier=k)
        add(f"s{s}-scale-2pc", ud, w("scale", P=P * 1.02), expect="scale")
    ud = sets[1]
    P, c = ud.P, ud.columns()

    def w(n, ud=ud, **kw):
        return ud.write(os.path.join(top, f"s1-{n}.csv"), **kw)
    Pz = P.copy()
    Pz[..., 2] *= -1
    add("s1-z-flipped", ud, w("zflip", P=Pz))
    add("s1-J1-J4-swapped", ud, w("j14", cols={**c, "J1": c["J4"], "J4": c["J1"]}))
    add("s1-J5-flipped", ud, w("j5flip", cols={**c, "J5": -c["J5"]}))
    add("s1-base-link-link_1", ud, ud.csv, base="link_1")
    add("s1-tip-link-link_5", ud, ud.csv, tip="link_5")
    add("s1-tip-link-flange", ud, ud.csv, tip="flange", expect="ok")
    add("s1-no-joint-map", ud, ud.csv, jmap="")
    add("s1-unknown-column", ud, w("temp", extra={"temp": ud.np.full(len(ud.q), 21.5)}))
    add("s1-ignored-column", ud, w("temp-ok", extra={"temp": ud.np.full(len(ud.q), 21.5)}),
        expect="ok", flags=["--ignore-columns", "temp"])
    half = w("half")
    lines = open(half).read().splitlines()
    head = lines[0].split(",")
    for i in range(1, len(lines)):
        cells = lines[i].split(",")
        if cells[head.index("m2_y")]:
            cells[head.index("m2_y")] = cells[head.index("m2_z")] = ""
            lines[i] = ",".join(cells)
            break
    with open(half, "w") as f:
        f.write("\n".join(lines) + "\n")
    add("s1-point-half-empty", ud, half)
    add("s1-ok-xyz-columns", ud, w("xyz", style="xyz"), expect="ok")
    fit, held = slice(0, 60), slice(60, 80)
    add("s1-validation-other-frame", ud, w("fit-only", use=False, rows=fit), flags=[
        "--validation", sets[2].write(os.path.join(top, "s2-held.csv"), use=False, rows=held)])
    add("s1-validation-file", ud, w("fit-only", use=False, rows=fit), expect="ok", flags=[
        "--validation", ud.write(os.path.join(top, "s1-held.csv"), use=False, rows=held)])
    add("s3-ok-any-frame", anyframe, anyframe.csv, expect="ok")
    add("s3-x-flipped", anyframe, anyframe.write(
        os.path.join(top, "s3-xflip.csv"), P=anyframe.P * [-1, 1, 1]))
    return C


def sim_control_cases(root: str, d: str) -> list[tuple[str, dict, str]]:
    """Control-port commands: (name, command, refuse|ok)."""
    bad = [("drop_prob", "lots"), ("drop_prob", -1), ("drop_prob", 2), ("drop_prob", None),
           ("corrupt_prob", "x"), ("late_s", "slow"), ("late_s", -1), ("late_s", 1e300),
           ("silent_nodes", "abc"), ("silent_nodes", [999]), ("silent_nodes", 5),
           ("drive_fault_node", "x"), ("drive_fault_node", 1.5), ("modbus_exception", 999),
           ("modbus_exception", "x"), ("inclinometer_silent", "maybe"),
           ("inclinometer_lag_s", -1), ("inclinometer_lag_s", "x"), ("drawwire_down", 2),
           ("drawwire_unanswered", -1), ("bogus", 1)]
    out = [(f"sim-fault-{k}-{v!r}"[:50], {"faults": {k: v}}, "refuse") for k, v in bad]
    out += [("sim-fault-ok", {"faults": {"drop_prob": 0.0}}, "ok"),
            ("sim-move-nan", {"move": ["nan", 0, 0, 0]}, "refuse"),
            ("sim-move-short", {"move": [0]}, "refuse"),
            ("sim-not-object", [1, 2], "refuse")]
    return out


def run_sim_control(root: str, d: str, verbose: bool) -> list[dict]:
    """Start ``app.py simulate``, send each control command, then ``clear`` and check that
    ``devices check`` against it still passes (every device thread alive)."""
    env = dict(os.environ, PYTHONPATH=root)
    ep = os.path.join(d, "sim-ep.json")
    proc = subprocess.Popen([sys.executable, os.path.join(root, "app.py"), "simulate",
                             "--robot", "agebot-sm", "--endpoints", ep], cwd=d, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    results = []
    try:
        endpoints = json.loads(proc.stdout.readline())
        host, port = endpoints["control"]["host"], endpoints["control"]["port"]
        for name, cmd, expect in sim_control_cases(root, d):
            s = socket.create_connection((host, port), timeout=5)
            f = s.makefile("rwb")
            f.write((json.dumps(cmd) + "\n").encode())
            f.flush()
            answer = json.loads(f.readline())
            time.sleep(0.5)              # the device threads meet the value
            f.write(b'{"clear": true}\n')
            f.flush()
            f.readline()
            s.close()
            time.sleep(1.2)
            chk = subprocess.run([sys.executable, os.path.join(root, "app.py"), "devices",
                                  "check", "--endpoints", ep, "--seconds", "0.3"], cwd=d,
                                 env=env, capture_output=True, text=True, timeout=60)
            refused = "error" in answer
            res = {"name": name, "rc": 0 if not refused else 2, "seconds": 0.0,
                   "wrong": expect == "refuse" and not refused,
                   "changed": chk.returncode != 0,        # a device thread died
                   "hang": False, "traceback": False, "messy": False,
                   "stderr": answer.get("error", "")[:200]}
            results.append(res)
            if verbose:
                print(json.dumps(res), flush=True)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return results


def run_case(root: str, d: str, c: Case) -> dict:
    env = dict(os.environ, PYTHONPATH=root, QT_QPA_PLATFORM="offscreen")
    before = {f: sha(f) for f in c.inputs}
    t0 = time.monotonic()
    hang, tb, outs = False, False, []
    for argv in [c.argv, *c.then]:
        proc = subprocess.Popen([sys.executable, os.path.join(root, "app.py"), *argv], cwd=d,
                                env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                stdin=subprocess.DEVNULL, text=True, start_new_session=True)
        try:
            so, se = proc.communicate(timeout=c.timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            so, se = proc.communicate()
            hang = True
        rc = proc.returncode
        outs.append(so)
        tb = tb or "Traceback (most recent call last)" in se
        if hang or rc != 0:
            break
    dt = time.monotonic() - t0
    changed = [f for f in c.inputs if sha(f) != before[f]]
    changed += [n for n in c.nodes if not os.path.exists(n)
                or stat.S_ISREG(os.stat(n).st_mode)]
    changed += [a for a in c.absent if os.path.exists(a)]
    lines = se.strip().splitlines()
    one = rc == 2 and len(lines) == 1 and lines[0].startswith("error: ")
    # accepted: is the answer right? (a case without a check: exit 0 is all it asks)
    wrong_answer, figures = "", ""
    if not hang and rc == 0 and c.expect == "ok" and c.check is not None:
        try:
            wrong_answer, figures = c.check("".join(outs))
        except Exception as e:  # noqa: BLE001 - a sweep's own fault, said as such
            wrong_answer = f"the sweep's check failed: {type(e).__name__}: {e}"
    res = {"name": c.name, "rc": rc, "seconds": round(dt, 2), "hang": hang,
           "wrong": (not hang) and rc == 0 and (c.expect == "refuse" or bool(wrong_answer)),
           "changed": changed, "traceback": tb,
           "messy": (not hang) and not tb and rc != 0 and not one,
           "unexpected_refusal": (not hang) and rc != 0 and c.expect == "ok",
           "stderr": (lines[-1] if lines else "")[:300], "argv": c.argv}
    if c.then:
        res["steps"] = len(outs)
        res["stdout"] = "".join(outs)[-3000:]
    if figures:
        res["check"] = figures
    if wrong_answer:
        res["check"] = "wrong answer: " + wrong_answer
    # a device node that became a file: put the device back (root) for the next cases
    for n in c.nodes:
        if os.path.exists(n) and stat.S_ISREG(os.stat(n).st_mode):
            os.unlink(n)
            dev = (1, 7) if "full" in n else (1, 3)
            try:
                os.mknod(n, 0o666 | stat.S_IFCHR, os.makedev(*dev))
            except OSError:
                os.mkfifo(n)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--root", default=HERE, help="the checkout whose app.py is run")
    ap.add_argument("--only", default="", help="run the cases whose name starts so")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", help="write every case's outcome here")
    ap.add_argument("--no-sim", action="store_true", help="skip the control-port cases")
    ap.add_argument("--keep", action="store_true", help="keep the working folder (its path "
                    "is printed)")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    root = os.path.abspath(a.root)
    d = tempfile.mkdtemp(prefix="sweep-edges-")
    _here_on_path()
    from drivers.sim.hung_server import HungServer

    hung = HungServer()
    dead = socket.socket()
    dead.bind(("127.0.0.1", 0))
    dead_port = dead.getsockname()[1]
    dead.close()
    p = setup(root, d)
    cs = [c for c in cases(p, d, hung.port, dead_port) if c.name.startswith(a.only)]
    if "data-rf-".startswith(a.only) or a.only.startswith("data-rf-"):
        cs += [c for c in serial_data_cases(root, d) if c.name.startswith(a.only)]
    if "data-urdf-".startswith(a.only) or a.only.startswith("data-urdf-"):
        cs += [c for c in urdf_data_cases(root, d) if c.name.startswith(a.only)]
    if "u43-".startswith(a.only) or a.only.startswith("u43-"):    # issue 43: URDF and CSV
        from sweep_urdf_edges import urdf_edge_cases

        cs += [c for c in urdf_edge_cases(root, d, Case) if c.name.startswith(a.only)]
    t0 = time.monotonic()
    results = []

    def serial():        # the output cases, one at a time: each may destroy its inputs
        for c in cs:
            if c.name.startswith("out-"):
                yield run_case(root, d, c)
                for dst, src in OWN.items():
                    if sha(dst) != sha(src):
                        shutil.copy(src, dst)

    with ThreadPoolExecutor(a.jobs) as ex:
        rest = ex.map(lambda c: run_case(root, d, c), [c for c in cs
                                                       if not c.name.startswith("out-")])
        import itertools
        for r in itertools.chain(serial(), rest):
            results.append(r)
            if a.verbose or r["wrong"] or r["changed"] or r["hang"] or r["traceback"] \
                    or r["messy"] or r["unexpected_refusal"]:
                flags = [k for k in ("wrong", "changed", "hang", "traceback", "messy",
                                     "unexpected_refusal") if r[k]]
                print(f"{r['name']:<45} rc {r['rc']} {r['seconds']:6.1f} s "
                      f"{','.join(flags) or 'fine'}  {(r.get('check') or r['stderr'])[:150]}",
                      flush=True)
    if not a.no_sim and "sim-".startswith(a.only[:4]):
        for r in run_sim_control(root, d, a.verbose):
            r["unexpected_refusal"] = False
            results.append(r)
            if r["wrong"] or r["changed"]:
                print(f"{r['name']:<45} {'wrong ' if r['wrong'] else ''}"
                      f"{'device thread dead' if r['changed'] else ''} {r['stderr'][:100]}")
    counts = {k: sum(bool(r[k]) for r in results)
              for k in ("wrong", "changed", "hang", "traceback", "messy", "unexpected_refusal")}
    print(f"\n{len(results)} cases in {time.monotonic() - t0:.0f} s ({root}): "
          + ", ".join(f"{k} {v}" for k, v in counts.items()))
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"root": root, "counts": counts, "results": results}, f, indent=1)
    if a.keep:
        print(f"working folder kept: {d}")
    else:
        shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
