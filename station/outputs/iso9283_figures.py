"""The accuracy page's figures (:mod:`station.outputs.iso9283_page`), drawn with the
report's kit (:mod:`station.outputs.report_plotting`): per pose AP_P and RP_l before and
after, and each pose's attained points about their barycentre, the cycles' scatter RP
measures. mm throughout; each returned as the report's ``{"src", "alt", "caption"}``."""
from __future__ import annotations

import math

import numpy as np

from calibration import iso9283
from station.outputs import report_plotting as kit

BEFORE, AFTER, PREDICTED = "#7f7f7f", "#1f77b4", "#d62728"


def figures(f) -> list[dict]:
    """The figures of :class:`station.outputs.iso9283_csv.Figures` ``f``."""
    return [fig_poses(f), fig_scatter(f)]


@kit.styled(7)
def fig_poses(f) -> dict:
    from matplotlib.ticker import LogLocator

    fig = kit.figure(10.0, 2.9, left=0.75, bottom=0.45, top=0.55, right=0.2, wspace=0.3)
    ax_ap, ax_rp = fig.subplots(1, 2)
    x = np.arange(5)
    ap = {p: np.array([r.ap for r in f.res[p]]) * 1e3 for p in f.res}
    rp = {p: np.array([r.rp for r in f.res[p]]) * 1e3 for p in f.res}
    shown = [v for v in np.r_[ap["nominal"], ap["compensated"], f.predicted * 1e3]
             if math.isfinite(v) and v > 0]
    floor = 10.0 ** math.floor(math.log10(min(shown)) - 0.3) if shown else 1e-3
    for dx, prog, color, label in ((-0.2, "nominal", BEFORE, "before (nominal program)"),
                                   (0.2, "compensated", AFTER, "after (compensated)")):
        bars = ax_ap.bar(x + dx, np.maximum(ap[prog], floor * 1.2) - floor, 0.4, bottom=floor,
                         color=color, label=label)
        ax_ap.bar_label(bars, labels=[f"{v:.3f}" for v in ap[prog]], fontsize=6, padding=1)
        bars = ax_rp.bar(x + dx, rp[prog], 0.4, color=color, label=label)
        ax_rp.bar_label(bars, labels=[f"{v:.3f}" for v in rp[prog]], fontsize=6, padding=1)
    if np.isfinite(f.predicted).all():
        ax_ap.plot(x + 0.2, f.predicted * 1e3, ls="none", marker="_", ms=14, mew=1.6,
                   color=PREDICTED, label="after, predicted by the calibration (std)")
    ax_ap.set_yscale("log")
    ax_ap.set_ylim(floor, max(shown) * 10 if shown else 1.0)
    ax_rp.set_ylim(0, max(float(np.max(np.r_[rp["nominal"], rp["compensated"]])), 1e-3) * 1.3)
    for ax, what in ((ax_ap, "pose accuracy AP_P [mm], log scale"),
                     (ax_rp, "pose repeatability RP_l [mm]")):
        ax.set_xticks(x, list(iso9283.POINTS))
        kit.title(ax, what)
        kit.style(ax, 7, minor=False)
    ax_ap.yaxis.set_major_locator(LogLocator(numticks=6))
    handles, labels = ax_ap.get_legend_handles_labels()
    order = sorted(range(len(labels)), key=lambda i: labels[i].startswith("after, predicted"))
    fig.legend([handles[i] for i in order], [labels[i] for i in order], fontsize=7,
               frameon=False, loc="upper center", ncol=3)
    return kit.img(fig, "AP_P and RP_l per pose, before and after the calibration",
                   "Per measuring pose: the pose accuracy AP_P (the distance of the attained "
                   "positions' barycentre from the commanded position; log scale, so that "
                   "\u201cafter\u201d stays visible) and the pose repeatability RP_l (the "
                   "radius l\u0304 + 3 S_l of the sphere the attained positions scatter in), "
                   "before (the nominal program) and after (the compensated program). The red "
                   "marks: the calibration's own predicted error (std) of the tool at the "
                   "compensated poses.")


@kit.styled(7)
def fig_scatter(f) -> dict:
    fig = kit.figure(10.0, 4.2, left=0.7, bottom=0.5, top=0.55, right=0.2, wspace=0.35,
                     hspace=0.45)
    axes = fig.subplots(2, 5, squeeze=False)
    reach = max([float(np.abs(d).max()) for p in f.scatter for d in f.scatter[p] if d.size]
                + [r.rp for p in f.res for r in f.res[p]] + [1e-6]) * 1e3 * 1.1
    circle = np.linspace(0.0, 2 * math.pi, 97)
    for k, pose in enumerate(iso9283.POINTS):
        for row, (a, b) in enumerate(((0, 1), (0, 2))):
            ax = axes[row][k]
            for prog, color, mark, label in (("nominal", BEFORE, "o", "before"),
                                             ("compensated", AFTER, "x", "after")):
                d = f.scatter[prog][k] * 1e3
                ax.plot(d[:, a], d[:, b], ls="none", marker=mark, ms=3, color=color,
                        label=label)
                r = f.res[prog][k].rp * 1e3
                ax.plot(r * np.cos(circle), r * np.sin(circle), lw=0.8, color=color,
                        ls="--" if prog == "nominal" else "-", label=f"RP_l {label}")
            ax.set_xlim(-reach, reach)
            ax.set_ylim(-reach, reach)
            ax.set_aspect("equal")
            kit.style(ax, 6, nbins=4)
            if row == 0:
                kit.title(ax, pose)
            ax.set_xlabel("x [mm]", fontsize=7)
            if k == 0:
                ax.set_ylabel(f"{'yz'[row]} [mm]", fontsize=7)
    fig.legend(*axes[0][0].get_legend_handles_labels(), fontsize=7, frameon=False,
               loc="upper center", ncol=4)
    return kit.img(fig, "the attained positions about their barycentre, per pose",
                   f"Each pose's attained positions less their barycentre over the "
                   f"{f.cycles} cycles, along the base link frame's axes (top: x and y, "
                   "bottom: x and z), before (o) and after (x), with the circle of radius "
                   "RP_l of each (its sphere's section). A calibration moves the barycentre "
                   "(AP), not this scatter (RP): it is the robot's own and the instrument's.")
