"""The report's drawing kit (:mod:`station.outputs.report_figures`): a figure on its own
Agg canvas with fixed margins, the PNG data URI, the report's look as an rc context,
tick locators and plain-text log labels, panels on a grid, one colour and dash per
line (also the wizard's plots). matplotlib is imported only when a figure is drawn."""
from __future__ import annotations

import base64
import functools
import io
import math
import re

DPI = 96
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#843c39", "#7b4173",
          "#3182bd", "#e6550d")


def finite(v) -> bool:
    try:
        return v is not None and not isinstance(v, bool) and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def figure(width, height, **margins):
    """A figure on its own Agg canvas (no pyplot). Margins are fixed, in inches
    (left, right, bottom, top), plus ``wspace``/``hspace``: cheaper than a layout
    engine and the same for every report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    m = {"left": 0.75, "right": 0.2, "bottom": 0.5, "top": 0.3, **margins}
    fig.subplots_adjust(left=m["left"] / width, right=1 - m["right"] / width,
                        bottom=m["bottom"] / height, top=1 - m["top"] / height,
                        wspace=m.get("wspace", 0.2), hspace=m.get("hspace", 0.2))
    return fig


def png(fig) -> str:
    """The figure drawn once on its Agg canvas and encoded as an RGB PNG (the figures are
    opaque: no alpha channel to store) at zlib level 2, base64. Measured on the report's
    figures against savefig's RGBA at level 6: 40 % less encoding time, files the same
    size or smaller; no metadata (no time stamp, no software version)."""
    from PIL import Image

    for ax in fig.axes:
        if ax.get_visible():
            trim_ticks(ax)
    fig.canvas.draw()
    w, h = fig.canvas.get_width_height(physical=True)
    rgb = Image.frombuffer("RGBA", (w, h), fig.canvas.buffer_rgba(), "raw", "RGBA", 0,
                           1).convert("RGB")
    buf = io.BytesIO()
    rgb.save(buf, format="png", compress_level=2)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def trim_ticks(ax) -> None:
    """The axes' ticks where its locators put them, fixed, and only those inside the
    axes' final limits. A locator also returns positions beyond the limits, and matplotlib
    makes a tick (five artists) for each, drawn or not; a tick costs about 1 ms of CPU
    (measured), a third of the report's figures. An axis without a label gets its
    label's place fixed (matplotlib otherwise measures the tick labels to place an empty
    label, per draw). Call once the limits are set."""
    from matplotlib.ticker import FixedLocator, NullLocator

    for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        if not axis.label.get_text():
            axis.set_label_coords(0.5, 0.5)
        lo, hi = min(lo, hi), max(lo, hi)
        pad = (hi - lo) * 1e-9
        for which, get, locator in (("major", axis.get_majorticklocs, axis.get_major_locator),
                                    ("minor", axis.get_minorticklocs, axis.get_minor_locator)):
            if isinstance(locator(), (FixedLocator, NullLocator)):
                continue
            locs = [v for v in get() if lo - pad <= v <= hi + pad]
            fixed = FixedLocator(locs)
            (axis.set_major_locator if which == "major" else axis.set_minor_locator)(fixed)


def img(fig, alt: str, caption: str) -> dict:
    return {"src": "data:image/png;base64," + png(fig), "alt": alt, "caption": caption}


SUPERSCRIPT = str.maketrans("-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075"
                                            "\u2076\u2077\u2078\u2079")


def plain_text(label: str) -> str:
    """A log axis' mathtext tick label (``$\\mathdefault{2\\times10^{-3}}$``) as plain
    text with superscript digits (``2\u00d710\u207b\u00b3``): the same reading without
    matplotlib's mathtext parser (0.34 of the 3.1 s the figures took under the profiler)."""
    m = re.fullmatch(r"\$\\mathdefault\{(.*)\}\$", label)
    if not m:
        return label
    body = re.sub(r"\^\{(-?\d+)\}", lambda e: e[1].translate(SUPERSCRIPT), m[1])
    return body.replace("\\times", "\u00d7").replace("-", "\u2212")


@functools.cache
def log_formatter():
    """matplotlib's log-axis formatter giving :func:`plain_text` labels (a class made on
    first use: matplotlib is imported only when a report is drawn)."""
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return plain_text(super().__call__(x, pos))

    return PlainLogFormatter


def title(ax, text: str, fs=8):
    """The axes' title at a fixed height (no search for overlapping tick labels per
    draw: the figures keep their x tick labels below the axes)."""
    ax.set_title(text, fontsize=fs, y=1.0)


def styled(fs: int, grid: str = "both"):
    """Decorator: the figure function runs (and draws) in matplotlib's rc context of the
    report's look: tick labels of ``fs`` points, a light major grid on ``grid`` ("both",
    "x", "y"), no top and right spines, text without FreeType's hinting (as legible at
    96 dpi, looked at; a third less CPU per text, and the report draws about 200). Set
    when the axes and ticks are made, not restyled per axes afterwards (each tick is a
    handful of artists to update)."""
    rc = {"xtick.labelsize": fs, "ytick.labelsize": fs, "axes.grid": True,
          "axes.grid.which": "major", "axes.grid.axis": grid, "grid.alpha": 0.35,
          "grid.linewidth": 0.6, "axes.spines.top": False, "axes.spines.right": False,
          "text.hinting": "no_hinting"}

    def wrap(fn):
        @functools.wraps(fn)
        def run(*args, **kwargs):
            from matplotlib import rc_context

            with rc_context(rc):
                return fn(*args, **kwargs)
        return run
    return wrap


def style(ax, fs=None, nbins=None, minor=True, iterations=False):
    """Locators and formatters of an axes. ``nbins``: at most that many intervals
    between the major ticks of a linear axis (small panels: fewer ticks to make and
    draw); ``minor=False``: no minor ticks on a log axis; ``iterations``: the x axis
    counts iterations (whole numbers only). ``fs``: also the look of :func:`styled`
    (tick labels of ``fs`` points, grid, spines), for a figure drawn outside it."""
    from matplotlib.ticker import MaxNLocator, NullLocator

    for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
        if scale == "log":
            fmt = log_formatter()
            axis.set_major_formatter(fmt())
            axis.set_minor_formatter(fmt(labelOnlyBase=False))
            if not minor:
                axis.set_minor_locator(NullLocator())
        elif nbins or (iterations and axis is ax.xaxis):
            axis.set_major_locator(MaxNLocator(nbins or "auto", steps=[1, 2, 2.5, 5, 10],
                                               integer=iterations and axis is ax.xaxis))
    if fs:
        ax.tick_params(which="both", labelsize=fs)
        ax.grid(True, which="major", alpha=0.35, linewidth=0.6)
        for side in ("top", "right"):
            ax.spines[side].set_visible(False)


def panels(fig, n: int, ncol: int) -> list:
    """``n`` axes on a grid of ``ncol`` columns, row by row; no axes where the grid is
    left empty."""
    gs = fig.add_gridspec(math.ceil(n / ncol), ncol)
    return [fig.add_subplot(gs[a // ncol, a % ncol]) for a in range(n)]


def marker(n):
    return "o" if n <= 60 else None


def line_style(n: int) -> dict:
    """The n-th line's colour and dash: every line told apart, however many (the
    colours first, solid, then again dashed, then dotted)."""
    return {"color": COLORS[n % len(COLORS)],
            "ls": ("-", "--", ":")[(n // len(COLORS)) % 3]}


def legend_right(n: int) -> float:
    """Inches right of the axes for a legend of ``n`` parameter names (a column per 18)."""
    return 1.9 * legend_columns(n) + 0.1


def legend_columns(n: int) -> int:
    return max(1, math.ceil(n / 18))
