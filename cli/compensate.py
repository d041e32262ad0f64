"""``app.py compensate PARAMS.json --program IN.csv --out OUT.csv``: a program's joint
values rewritten for the calibrated robot (:func:`station.outputs.compensate.main`,
docs/compensation.md)."""
from __future__ import annotations

from cli.common import delegate


def add_parser(sub) -> None:
    cp = sub.add_parser("compensate", help="a program's joint values rewritten so that the "
                        "calibrated robot reaches the nominal targets (docs/compensation.md)")
    cp.add_argument("params", help="the parameter file")
    cp.add_argument("--program", required=True, metavar="IN.csv",
                    help="joint values as the nominal controller runs them, a row per target "
                         "(other columns are passed through)")
    cp.add_argument("--out", required=True, metavar="OUT.csv")
    cp.add_argument("--angle-unit", choices=("rad", "deg"),
                    help="URDF robots: unit of the revolute joints' columns (default rad)")
    cp.add_argument("--length-unit", choices=("m", "mm"),
                    help="URDF robots: unit of the prismatic joints' columns (default m)")
    cp.add_argument("--joint-map", metavar="FILE",
                    help="URDF robots: how the URDF's joints follow from the controller's "
                         "columns (docs/urdf-robots.md); written back into them")
    cp.set_defaults(func=delegate("station.outputs.compensate", "main"))
