"""``app.py study --method M --robots N --out DIR``: Monte Carlo calibrations over robots
drawn around the nominal, on Dask (:func:`station.simulation.study.cli`, docs/design.md)."""
from __future__ import annotations

from cli.common import add_chain_arguments, delegate


def add_parser(sub) -> None:
    st = sub.add_parser("study", help="Monte Carlo calibrations over robots drawn around the "
                        "nominal, on Dask (docs/design.md)")
    st.add_argument("--method", required=True)
    st.add_argument("--robot", help="the method's robot (default: the one it is for)")
    add_chain_arguments(st)
    st.add_argument("--robots", type=int, required=True, help="robots to draw")
    st.add_argument("--design", default="optimal,random",
                    help="pose designs to compare, comma-separated (optimal, random)")
    st.add_argument("--count", type=int, help="poses per calibration (default: eq. 60)")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--gear", type=float, default=0.4, help="gear ratios within +-GEAR (relative)")
    st.add_argument("--length", type=float, default=0.05, help="lengths within +-LENGTH (relative)")
    st.add_argument("--offset", type=float, default=0.03, help="offsets within +-OFFSET")
    st.add_argument("--noise", action="append", metavar="CHANNEL=STD",
                    help="reading noise (default: the station's devices averaged over 5 samples)")
    st.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:PORT (default: "
                    "a local cluster)")
    st.add_argument("--workers", type=int, help="local cluster: worker processes (default: cores)")
    st.add_argument("--out", required=True, help="folder for study.jsonl and summary.json")
    st.set_defaults(func=delegate("station.simulation.study", "cli"), robot_chain=True)
