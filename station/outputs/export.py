"""Exports of a robot file's calibration (``app.py params export``): URDF for a
controller or a ROS stack, and a calibrated robot file the station reads back.

Both start from a parameter file of a robot file (its ``robot_file`` and the
calibrated ``parameters``): :func:`calibrated_model` gives the model and the
calibrated vector, every parameter the fit did not calibrate at its start value.

URDF (docs/robot-files.md, "URDF export of a calibrated robot file"): links ``base_link`` (the base
frame F_b), ``link1 .. linkn`` and ``tool0`` (the tool frame F_e); joint i is a
revolute or prismatic joint about z whose position is the actuator value
``qm_i``. Each joint's constant transforms are split around its motion factor
(``pre`` before, ``post`` after: the offset goes into ``pre``), and joint i's
origin is ``post_{i-1} pre_i`` (``post_0`` the base compensation); a fixed joint
``post_n T_tool`` carries the tool. A transmission ratio other than 1 cannot be
held by URDF: the export refuses, naming the joint. Origins are written with 17
significant digits, so the URDF's forward kinematics equals the model's to
round-off (rpy of the origins are exact away from pitch = +-pi/2).
"""
from __future__ import annotations

import hashlib

import json
import math
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from calibration.chain import Chain
from calibration.errors import ConfigError
from calibration.robots import get_robot
from calibration.robots.serial import FRAME_KEYS, rpy_of
from drivers.robot_file import FORMAT, VERSION, format_float, spec_from_source

K_TOL = 1e-12  # |k - 1| above which URDF cannot hold the joint


def calibrated_model(doc: dict, source: str = "parameter file"):
    """``(robot, xi)`` of a parameter file of a robot file."""
    if "robot_file" not in doc:
        raise ConfigError(f"robot {doc.get('robot')!r} is not from a robot file: the "
                          f"exports take a robot file's calibration", source=source)
    robot = get_robot(spec_from_source(doc["robot_file"], f"{source}: robot_file"))
    params = doc["parameters"]
    xi = robot.nominal.copy()
    for j, name in enumerate(robot.param_names):
        if name in params:
            xi[j] = float(params[name]["value"])
    return robot, xi


def _transform(chain: Chain, factors, xi) -> np.ndarray:
    """The product of constant ``factors`` (no joint) at ``xi``."""
    sub = Chain(tuple(factors), chain.n_params, (), ())
    return sub.fk(np.zeros((1, 0)), xi)[0]


def joint_transforms(robot, xi):
    """``(origins, kinds, tool)``: the origin (4x4) of each joint relative to the link
    before it (``base_link`` for joint 1), the joints' kinds, and the fixed
    ``tool0`` origin relative to the last link (module doc)."""
    fs = robot.chain.factors
    motion = [j for j, f in enumerate(fs) if f.joint is not None]
    origins, kinds = [], []
    for n, j in enumerate(motion):
        start = 0 if n == 0 else motion[n - 1] + 1
        off = float(xi[robot.chain.offset_idx[n]])
        shift = np.eye(4)  # the offset: Rot(z, off) or Trans(z, off) at the motion factor
        kind = robot.spec.joints[n].kind
        if kind == "R":
            c, s = math.cos(off), math.sin(off)
            shift[:2, :2] = [[c, -s], [s, c]]
        else:
            shift[2, 3] = off
        origins.append(_transform(robot.chain, fs[start:j], xi) @ shift)
        kinds.append(kind)
    tool = _transform(robot.chain, fs[motion[-1] + 1:], xi)
    return origins, kinds, tool


def _origin(T) -> str:
    xyz = " ".join(repr(float(v)) for v in T[:3, 3])
    rpy = " ".join(repr(float(v)) for v in rpy_of(T[None, :3, :3])[0])
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def urdf_text(robot, xi) -> str:
    """The URDF of the calibrated ``robot`` at ``xi`` (module doc)."""
    for i, jt in enumerate(robot.spec.joints, start=1):
        k = float(xi[robot.index(f"k{i}")])
        if abs(k - 1.0) > K_TOL:
            raise ConfigError(f"joint {i}: k{i} = {k:.12g} is not 1; URDF has no transmission "
                              f"ratio (export the robot file instead, or hold k{i} = 1)",
                              source="URDF export")
    origins, kinds, tool = joint_transforms(robot, xi)
    lines = ['<?xml version="1.0"?>',
             f"<robot name={quoteattr(robot.name)}>",
             '  <link name="base_link"/>']
    parent = "base_link"
    for i, (origin, kind, jt) in enumerate(zip(origins, kinds, robot.spec.joints), start=1):
        child = f"link{i}"
        lo, hi = jt.limits
        lines += [f'  <link name="{child}"/>',
                  f'  <joint name="joint{i}" type="{"revolute" if kind == "R" else "prismatic"}">',
                  f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
                  f"    {_origin(origin)}", '    <axis xyz="0 0 1"/>',
                  f'    <limit lower="{lo!r}" upper="{hi!r}" effort="0" velocity="0"/>',
                  "  </joint>"]
        parent = child
    lines += ['  <link name="tool0"/>', '  <joint name="tool0_joint" type="fixed">',
              f'    <parent link="{parent}"/>', '    <child link="tool0"/>',
              f"    {_origin(tool)}", "  </joint>", "</robot>", ""]
    return "\n".join(lines)


def robot_file_text(robot, xi, comment: str = "") -> str:
    """A robot file (TOML) of the calibrated ``robot`` at ``xi``: the same joints,
    limits and ``fixed``, every value the calibrated one."""
    v = {n: float(x) for n, x in zip(robot.param_names, xi)}
    f = format_float
    out = [f"# {line}" for line in comment.splitlines()] + [
        f'format = "{FORMAT}"', f"version = {VERSION}", f"name = {_q(robot.name)}"]
    if robot.fixed:
        out.append("fixed = [" + ", ".join(_q(n) for n in robot.fixed) + "]")
    out += ["", "[base]"] + [f"{k} = {f(v[f'base_{k}'])}" for k in FRAME_KEYS]
    for i, jt in enumerate(robot.spec.joints, start=1):
        out += ["", "[[joint]]", f'type = "{jt.kind}"']
        if jt.kind == "P":
            out.append(f"theta = {f(v[f'theta{i}'])}")
        elif not jt.hayati:
            out.append(f"d = {f(v[f'd{i}'])}")
        out += [f"a = {f(v[f'a{i}'])}", f"alpha = {f(v[f'alpha{i}'])}"]
        if jt.hayati:
            out.append(f"beta = {f(v[f'beta{i}'])}")
        out += [f"k = {f(v[f'k{i}'])}", f"offset = {f(v[f'q{i}_off'])}",
                f"limits = [{f(jt.limits[0])}, {f(jt.limits[1])}]"]
    out += ["", "[tool]"] + [f"{k} = {f(v[f'tool_{k}'])}" for k in FRAME_KEYS]
    return "\n".join(out) + "\n"


def _q(s: str) -> str:
    """A TOML basic string of ``s`` that reads back to ``s`` (control characters escaped)."""
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")



def _replaceable(path, kind: str, own: str | None) -> None:
    """An existing ``path`` is replaced only by its kind (``"urdf"``: a URDF, ``"robot
    file"``: a TOML robot file) and never where it is the robot's own description (its
    sha256 ``own``, the file the calibration started from): a trace, a parameter file, a
    CSV or the robot's own URDF would be lost (``params export P --urdf TRACE.jsonl``
    replaced the only copy of the measurements)."""
    p = Path(path)
    if not p.is_file():
        return
    raw = p.read_bytes()
    head = raw[:4096].decode("utf-8", "replace").lstrip("\ufeff \t\r\n")
    looks = ("<robot" in head and head.startswith(("<?xml", "<robot", "<!--"))
             if kind == "urdf" else head.startswith(("#", "[", "name")))
    if not looks:
        raise ConfigError(f"cannot write the {'URDF' if kind == 'urdf' else kind} {path}: it "
                          f"exists and is not a {'URDF' if kind == 'urdf' else 'robot file'} "
                          "(it would be lost): choose another file name")
    if own is not None and hashlib.sha256(raw).hexdigest() == own:
        raise ConfigError(f"cannot write the calibrated {'URDF' if kind == 'urdf' else kind} "
                          f"{path}: it is the robot's own description, the one this calibration "
                          "started from (keep it: write the calibration beside it)")


def _refuse_compliant(doc: dict, path: str) -> None:
    """A compliant calibration's geometry predicts the tool only with its compliances (on
    TIAGo's data 2.9 mm held out with them, 11 mm without): a URDF, which holds the
    geometry alone, is not written from it (docs/compliance.md)."""
    bent = [n for n, v in (doc.get("parameters") or {}).items()
            if n[:1] == "c" and n[1:].isdigit() and isinstance(v, dict)
            and v.get("identifiable", True) and float(v.get("value") or 0.0) != 0.0]
    if bent:
        raise ConfigError(
            f"a compliant calibration ({', '.join(bent)}): a URDF holds the geometry alone, and "
            f"this geometry was fitted together with the compliances (without them it misses "
            f"the tool by what they bend); for a URDF export a rigid calibration (batch "
            f"without --compliance), and apply the compliances as docs/compliance.md says",
            source=path)


def export_command(args) -> list[str]:
    """``app.py params export FILE [--urdf OUT] [--robot-file OUT]``: check the
    parameter file (checksum), build the calibrated model, write each output
    atomically (all checks before the first write). Returns the lines to print."""
    from drivers.atomic import check_outputs, write_atomic
    from station.outputs.params_file import check_usable, read_params

    if args.urdf is None and args.robot_file is None:
        raise ConfigError("give --urdf OUT.urdf and/or --robot-file OUT.toml")
    check_outputs((args.urdf, "the URDF"), (args.robot_file, "the robot file"),
                  inputs=(args.file,))
    doc = read_params(args.file)
    check_usable(doc, args.file)
    own = (doc.get("robot_file") or {}).get("sha256")
    for path, kind in ((args.urdf, "urdf"), (args.robot_file, "robot file")):
        if path is not None:
            _replaceable(path, kind, own)
    robot, xi = calibrated_model(doc, args.file)
    outs = []
    urdf_robot = hasattr(robot, "calibrated_origins")
    if urdf_robot and args.robot_file:
        raise ConfigError(f"{robot.name} is a URDF robot: its calibration is exported into its "
                          f"own URDF (--urdf OUT.urdf), not as a robot file", source=args.file)
    if args.urdf and urdf_robot:
        from station.outputs.export_urdf import calibrated_urdf

        _refuse_compliant(doc, args.file)

        outs.append((args.urdf, calibrated_urdf(robot, xi), "calibrated URDF"))
    elif args.urdf:
        outs.append((args.urdf, urdf_text(robot, xi), "URDF"))
    if args.robot_file:
        note = (f"{robot.name} calibrated by {doc['method']} ({doc['created']}), from "
                f"{args.file} ({doc['checksum']})")
        outs.append((args.robot_file, robot_file_text(robot, xi, note), "calibrated robot file"))
    if args.robot_file:       # what is written must read back
        from drivers.robot_file import parse_robot_file

        parse_robot_file(outs[-1][1], f"the calibrated robot file {args.robot_file}")
    lines, written = [], []
    q = (doc.get("fit") or {}).get("quality") or {}
    if q.get("passed") is False:
        failed = "; ".join(c["message"] for c in q.get("checks", ()) if not c.get("ok"))
        lines.append(f"warning: this calibration failed the fit-quality gate and was kept with "
                     f"--accept-poor-fit ({failed[:300]}): the exported model carries that")
    try:
        for path, text, what in outs:
            write_atomic(path, text.encode("utf-8"))
            written.append(path)
            lines.append(f"{what} written to {path}")
    except BaseException:       # never half an export: the files written go again
        for path in written:
            Path(path).unlink(missing_ok=True)
        raise
    return lines
