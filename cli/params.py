"""``app.py params verify PARAMS.json`` (format, version, checksum, structure and values)
and ``app.py params export PARAMS.json --urdf OUT.urdf --robot-file OUT.toml``
(:func:`station.outputs.export.export_command`, docs/robot-files.md)."""
from __future__ import annotations

import sys


def add_parser(sub) -> None:
    pa = sub.add_parser("params", help="parameter files")
    psub = pa.add_subparsers(dest="params_command", required=True)
    v = psub.add_parser("verify", help="check format, version and checksum")
    v.add_argument("file")
    v.set_defaults(func=verify)
    ex = psub.add_parser("export", help="a robot file's calibration as URDF and/or a "
                                        "calibrated robot file (docs/robot-files.md)")
    ex.add_argument("file")
    ex.add_argument("--urdf", help="URDF to write (refused where a ratio k is not 1)")
    ex.add_argument("--robot-file", help="calibrated robot file (TOML) to write")
    ex.set_defaults(func=export)


def verify(args) -> int:
    from station.outputs.params_file import check_usable, read_params

    doc = read_params(args.file)
    check_usable(doc, args.file)
    n_id = sum(p["identifiable"] for p in doc["parameters"].values())
    accepted = (doc["fit"].get("quality") or {}).get("accepted")
    print(f"{args.file}: OK ({doc['format']} v{doc['version']}, robot {doc['robot']}, method "
          f"{doc['method']}, {n_id} of {len(doc['parameters'])} parameters calibrated, "
          f"{doc['checksum']})" + ("; a poor fit accepted on purpose (--accept-poor-fit): "
                                   "fit.quality says what failed" if accepted else ""))
    return 0


def export(args) -> int:
    from station.outputs.export import export_command

    for line in export_command(args):
        print(line, file=sys.stderr if line.startswith("warning:") else sys.stdout)
    return 0
