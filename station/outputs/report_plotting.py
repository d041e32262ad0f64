"""The report's drawing kit (:mod:`station.outputs.report_figures`): a figure on its own
canvas with fixed margins, the SVG data URI, the report's look as an rc context, tick
locators and plain-text log labels, a legend placed once, panels on a grid, one colour
and dash per line (also the wizard's plots). matplotlib is imported only when a figure
is drawn."""
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
    """A figure on its own Agg canvas (no pyplot; the report writes it with :func:`svg`).
    Margins are fixed, in inches (left, right, bottom, top), plus ``wspace``/``hspace``:
    cheaper than a layout engine and the same for every report."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    m = {"left": 0.75, "right": 0.2, "bottom": 0.5, "top": 0.3, **margins}
    fig.subplots_adjust(left=m["left"] / width, right=1 - m["right"] / width,
                        bottom=m["bottom"] / height, top=1 - m["top"] / height,
                        wspace=m.get("wspace", 0.2), hspace=m.get("hspace", 0.2))
    return fig


#: the SVG backend's settings: text written as <text> in the page's fonts (DejaVu Sans,
#: then its look-alikes), ids from a fixed salt (the same figure, the same file)
SVG_RC = {"svg.fonttype": "none", "svg.hashsalt": "calibration-report"}


def svg(fig) -> str:
    """The figure drawn once as SVG, base64: vector lines and text as <text> elements,
    which the browser draws, instead of glyphs rasterised by Agg and a PNG to encode
    (measured on the report's figures: about 0.05 s less per report, sharp at any
    zoom); no metadata (no time stamp, no software version)."""
    from matplotlib import rc_context
    from matplotlib.backends.backend_svg import FigureCanvasSVG

    for ax in fig.axes:
        if ax.get_visible():
            trim_ticks(ax)
    buf = io.StringIO()
    with rc_context(SVG_RC):
        FigureCanvasSVG(fig).print_svg(buf, metadata={"Date": None, "Creator": None})
    return base64.b64encode(buf.getvalue().encode("utf-8")).decode("ascii")


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
    return {"src": "data:image/svg+xml;base64," + svg(fig), "alt": alt, "caption": caption}


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
    "x", "y"), no top and right spines, text without FreeType's hinting where it is
    drawn in pixels (as legible at 96 dpi, looked at; a third less CPU per text). Set
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


def legend(ax, fontsize=7, anchor=(1.01, 1.0), handlelength=2.0, borderaxespad=0.5, ncol=1):
    """The axes' labelled lines listed from ``anchor`` (axes coordinates, the list's upper
    left corner), each as its line, its marker and its label, in ``ncol`` columns of
    :data:`LEGEND_COLUMN` inches filled in turn: the layout of matplotlib's
    ``ax.legend(loc="upper left", bbox_to_anchor=anchor, frameon=False)``, its spacing
    in font sizes (pad 0.4, rows 1.5 apart, the text 0.8 after the line; the same
    places to 0.05 pt, tested), placed once as a Line2D and a Text per entry.
    matplotlib's legend packs its entries in boxes laid out again per draw: 1.4-1.9 ms
    per entry (measured), and the report lists 56."""
    from matplotlib.lines import Line2D
    from matplotlib.transforms import Affine2D, ScaledTranslation

    at = (Affine2D().scale(1 / 72) + ax.figure.dpi_scale_trans     # points from the anchor
          + ScaledTranslation(*anchor, ax.transAxes))
    lines = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]
    rows = math.ceil(len(lines) / ncol)
    pad = (borderaxespad + 0.4) * fontsize
    for n, line in enumerate(lines):
        x0 = pad + n // rows * LEGEND_COLUMN * 72
        x1 = x0 + handlelength * fontsize
        y = -pad - (0.5 + 1.5 * (n % rows)) * fontsize       # the row's middle
        h = y + 0.09 * fontsize                              # the line a little above it
        ax.add_artist(Line2D([x0, (x0 + x1) / 2, x1], [h, h, h], transform=at,
                             color=line.get_color(), ls=line.get_linestyle(),
                             lw=line.get_linewidth(), marker=line.get_marker(),
                             ms=line.get_markersize(), markevery=[1], clip_on=False,
                             label=LEGEND))
        ax.text(x1 + 0.8 * fontsize, y, line.get_label(), transform=at, fontsize=fontsize,
                va="center", ha="left", clip_on=False, label=LEGEND)


def legend_entries(ax) -> list:
    """The (line, text) pairs of the axes' :func:`legend`, in order."""
    parts = [a for a in ax.get_children() if a.get_label() == LEGEND]
    return list(zip(parts[::2], parts[1::2]))


def segments(ax, x, y0, y1, **line):
    """Vertical lines from ``y0`` to ``y1`` at ``x`` as one Line2D, its path broken by NaN
    (the look of ``ax.vlines``, butt caps; ``marker``: drawn at the ``y1`` ends only).
    The SVG backend writes a LineCollection as a <path> per line, each with its style:
    the residuals figure took 0.12 s with vlines, 0.09 s so (measured)."""
    import numpy as np

    x, y0, y1 = (np.broadcast_to(np.asarray(v, dtype=float), np.shape(x)) for v in (x, y0, y1))
    xs = np.repeat(x, 3)
    ys = np.stack([y0, y1, np.full_like(y1, np.nan)], axis=1).ravel()
    xs[2::3] = np.nan
    return ax.plot(xs, ys, solid_capstyle="butt", markevery=slice(1, None, 3), **line)[0]


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


#: inches per column of a :func:`legend`, and the label of its artists (not a legend's)
LEGEND_COLUMN = 1.9
LEGEND = "_legend"


def legend_right(n: int) -> float:
    """Inches right of the axes for a legend of ``n`` parameter names (a column per 18)."""
    return LEGEND_COLUMN * legend_columns(n) + 0.1


def legend_columns(n: int) -> int:
    return max(1, math.ceil(n / 18))
