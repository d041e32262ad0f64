#!/usr/bin/env python3
"""Adversarial sweep of the command line (issue 27): a user's mistakes, outputs that
would destroy inputs, hung devices and silently wrong commands, each run as
``python app.py ...`` in a subprocess of a checkout.

    python bench/sweep_edges.py                     # this checkout, ~5 min
    python bench/sweep_edges.py --root /tmp/old     # another checkout (before/after)
    python bench/sweep_edges.py --only out- -v      # cases whose name starts so

Each case says what a careful tool does: ``refuse`` (a one-line ``error: ...`` on
stderr, exit 2), ``ok`` (exit 0) or ``either``. Counted:

- wrong:     exit 0 where the case must be refused (a confident wrong answer)
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
import threading
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
    timeout: float = HANG_S


class HungServer:
    """A TCP server that accepts connections and never says a word (a hung socketcand)."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(64)
        self.port = self.sock.getsockname()[1]
        self.conns = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                c, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(c)


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
    proc = subprocess.Popen([sys.executable, os.path.join(root, "app.py"), *c.argv], cwd=d,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            stdin=subprocess.DEVNULL, text=True, start_new_session=True)
    try:
        so, se = proc.communicate(timeout=c.timeout)
        hang = False
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        so, se = proc.communicate()
        hang = True
    dt = time.monotonic() - t0
    rc = proc.returncode
    changed = [f for f in c.inputs if sha(f) != before[f]]
    changed += [n for n in c.nodes if not os.path.exists(n)
                or stat.S_ISREG(os.stat(n).st_mode)]
    changed += [a for a in c.absent if os.path.exists(a)]
    lines = se.strip().splitlines()
    tb = "Traceback (most recent call last)" in se
    one = rc == 2 and len(lines) == 1 and lines[0].startswith("error: ")
    res = {"name": c.name, "rc": rc, "seconds": round(dt, 2), "hang": hang,
           "wrong": (not hang) and rc == 0 and c.expect == "refuse",
           "changed": changed, "traceback": tb,
           "messy": (not hang) and not tb and rc != 0 and not one,
           "unexpected_refusal": (not hang) and rc != 0 and c.expect == "ok",
           "stderr": (lines[-1] if lines else "")[:300], "argv": c.argv}
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
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    root = os.path.abspath(a.root)
    d = tempfile.mkdtemp(prefix="sweep-edges-")
    hung = HungServer()
    dead = socket.socket()
    dead.bind(("127.0.0.1", 0))
    dead_port = dead.getsockname()[1]
    dead.close()
    p = setup(root, d)
    cs = [c for c in cases(p, d, hung.port, dead_port) if c.name.startswith(a.only)]
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
                      f"{','.join(flags) or 'fine'}  {r['stderr'][:150]}", flush=True)
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
    shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
