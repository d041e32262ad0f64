"""The report's figures (station/outputs/report.py): matplotlib on its own Agg canvas (pyplot
and its global state are not used), each returned as ``{"src", "alt", "caption"}``
with the PNG embedded as a base64 data URI.

Parameters are plotted in SI (as in the parameter file), residuals and validation
errors in the display units of :mod:`station.outputs.units` (mm and degrees by default).
"""
from __future__ import annotations

import base64
import functools
import io
import math
import re

import numpy as np

DPI = 96
COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#843c39", "#7b4173",
          "#3182bd", "#e6550d")


def finite(v) -> bool:
    try:
        return v is not None and not isinstance(v, bool) and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _figure(width, height, **margins):
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


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(fig, alt: str, caption: str) -> dict:
    return {"src": "data:image/png;base64," + _png(fig), "alt": alt, "caption": caption}


_SUPERSCRIPT = str.maketrans("-0123456789", "\u207b\u2070\u00b9\u00b2\u00b3\u2074\u2075"
                                            "\u2076\u2077\u2078\u2079")


def _plain_text(label: str) -> str:
    """A log axis' mathtext tick label (``$\\mathdefault{2\\times10^{-3}}$``) as plain
    text with superscript digits (``2\u00d710\u207b\u00b3``): the same reading without
    matplotlib's mathtext parser (0.34 of the 3.1 s the figures took under the profiler)."""
    m = re.fullmatch(r"\$\\mathdefault\{(.*)\}\$", label)
    if not m:
        return label
    body = re.sub(r"\^\{(-?\d+)\}", lambda e: e[1].translate(_SUPERSCRIPT), m[1])
    return body.replace("\\times", "\u00d7").replace("-", "\u2212")


@functools.cache
def _log_formatter():
    """matplotlib's log-axis formatter giving :func:`_plain_text` labels (a class made on
    first use: matplotlib is imported only when a report is drawn)."""
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return _plain_text(super().__call__(x, pos))

    return PlainLogFormatter


def _title(ax, text: str, fs=8):
    """The axes' title at a fixed height (no search for overlapping tick labels per
    draw: the figures keep their x tick labels below the axes)."""
    ax.set_title(text, fontsize=fs, y=1.0)


def _styled(fs: int, grid: str = "both"):
    """Decorator: the figure function runs (and draws) in matplotlib's rc context of the
    report's look: tick labels of ``fs`` points, a light major grid on ``grid`` ("both",
    "x", "y"), no top and right spines. Set when the axes and ticks are made, not
    restyled per axes afterwards (each tick is a handful of artists to update)."""
    rc = {"xtick.labelsize": fs, "ytick.labelsize": fs, "axes.grid": True,
          "axes.grid.which": "major", "axes.grid.axis": grid, "grid.alpha": 0.35,
          "grid.linewidth": 0.6, "axes.spines.top": False, "axes.spines.right": False}

    def wrap(fn):
        @functools.wraps(fn)
        def styled(*args, **kwargs):
            from matplotlib import rc_context

            with rc_context(rc):
                return fn(*args, **kwargs)
        return styled
    return wrap


def _style(ax, fs=None, nbins=None, minor=True, iterations=False):
    """Locators and formatters of an axes. ``nbins``: at most that many intervals
    between the major ticks of a linear axis (small panels: fewer ticks to make and
    draw); ``minor=False``: no minor ticks on a log axis; ``iterations``: the x axis
    counts iterations (whole numbers only). ``fs``: also the look of :func:`_styled`
    (tick labels of ``fs`` points, grid, spines), for a figure drawn outside it."""
    from matplotlib.ticker import MaxNLocator, NullLocator

    for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
        if scale == "log":
            fmt = _log_formatter()
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


def _panels(fig, n: int, ncol: int) -> list:
    """``n`` axes on a grid of ``ncol`` columns, row by row; no axes where the grid is
    left empty."""
    gs = fig.add_gridspec(math.ceil(n / ncol), ncol)
    return [fig.add_subplot(gs[a // ncol, a % ncol]) for a in range(n)]


def _marker(n):
    return "o" if n <= 60 else None


def line_style(n: int) -> dict:
    """The n-th line's colour and dash: every line told apart, however many (the
    colours first, solid, then again dashed, then dotted)."""
    return {"color": COLORS[n % len(COLORS)],
            "ls": ("-", "--", ":")[(n // len(COLORS)) % 3]}


def _legend_right(n: int) -> float:
    """Inches right of the axes for a legend of ``n`` parameter names (a column per 18)."""
    return 1.9 * _legend_columns(n) + 0.1


def _legend_columns(n: int) -> int:
    return max(1, math.ceil(n / 18))


def figures(ctx) -> list[dict]:
    """The section 7 figures of a report context (:class:`station.outputs.report_context.ReportContext`):
    parameters, deviation, variance and condition number per iteration (when the
    solver recorded its history), then the residuals per channel."""
    hist = list(ctx.res.history)
    figs = []
    if hist:
        figs += [_fig_parameters(ctx, hist), _fig_deviation(ctx, hist),
                 _fig_variance(ctx, hist), _fig_condition(ctx, hist)]
    figs.append(_fig_residuals(ctx))
    return [f for f in figs if f]


def _series(ctx, hist):
    """Iterations 0..K and the parameters there (row 0: the start values)."""
    X = np.vstack([np.asarray(ctx.res.x0, dtype=float)] + [np.asarray(h.x, dtype=float)
                                                           for h in hist])
    return np.arange(len(X)), X


def _active(ctx):
    return [j for j, g in enumerate(ctx.groups) if g == "identifiable"]


@_styled(7, grid="y")
def _fig_parameters(ctx, hist) -> str:
    idx = _active(ctx)
    if not idx:
        return None
    from matplotlib.ticker import NullLocator

    k, X = _series(ctx, hist)
    ncol = 4 if len(idx) > 6 else min(3, len(idx))
    nrow = math.ceil(len(idx) / ncol)
    fig = _figure(2.5 * ncol, 1.8 * nrow + 0.5, left=0.6, bottom=0.55, top=0.3,
                  wspace=0.55, hspace=0.6)
    for a, (ax, j) in enumerate(zip(_panels(fig, len(idx), ncol), idx)):
        x_end, s = ctx.x[j], ctx.std[j]
        if finite(s) and s > 0:
            ax.axhspan(x_end - s, x_end + s, color="#d62728", alpha=0.15, lw=0)
        ax.axhline(x_end, color="#d62728", lw=0.8, ls="--")
        ax.plot(k, X[:, j], color="#1f77b4", lw=1.2, marker=_marker(len(k)), ms=2.5)
        unit = ctx.units.get(ctx.names[j], "")
        _title(ax, f"{ctx.names[j]}" + (f" [{unit}]" if unit else ""))
        _style(ax, nbins=4, iterations=True)
        if a + ncol < len(idx):     # the iterations are read under the column's last panel
            ax.xaxis.set_major_locator(NullLocator())
        ax.ticklabel_format(axis="y", useOffset=False, style="sci", scilimits=(-3, 4))
        ax.yaxis.get_offset_text().set_fontsize(7)
    fig.supxlabel("iteration k", fontsize=8, y=0.01)
    return _img(fig, "parameter values per iteration",
                "Calibrated parameters \u03be(k) per iteration (k = 0: start values); dashed: "
                "the calibrated value, band: \u00b1 1 std (report Fig. 10, 28).")


@_styled(8)
def _fig_deviation(ctx, hist) -> str:
    idx = [j for j in _active(ctx) if finite(ctx.std[j]) and ctx.std[j] > 0]
    if not idx:
        return None
    k, X = _series(ctx, hist)
    fig = _figure(10.0, 3.6, right=_legend_right(len(idx)), left=0.8)
    ax = fig.subplots()
    floor = 1e-6
    for n, j in enumerate(idx):
        d = np.abs(X[:, j] - ctx.x[j]) / ctx.std[j]
        ax.semilogy(k, np.maximum(d, floor), lw=1.1, marker=_marker(len(k)), ms=2.5,
                    label=ctx.names[j], **line_style(n))
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.text(k[-1], 1.0, " 1 std", va="bottom", ha="right", fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("|\u03be(k) \u2212 \u03be_final| / std", fontsize=8)
    ax.set_ylim(bottom=floor / 2)
    _style(ax, iterations=True)
    ax.legend(fontsize=7, ncol=_legend_columns(len(idx)), loc="upper left",
              bbox_to_anchor=(1.01, 1.0), frameon=False)
    return _img(fig, "parameter deviation from the final value in standard deviations",
                f"Convergence: distance of each identifiable parameter from its calibrated value "
                f"in units of its std (values below {floor:g} drawn at {floor:g}).")


@_styled(8)
def _fig_variance(ctx, hist) -> str:
    V = np.array([np.asarray(h.variance, dtype=float) for h in hist])
    k = np.arange(1, len(hist) + 1)
    cols = [j for j in range(V.shape[1]) if np.any(np.isfinite(V[:, j]) & (V[:, j] > 0))]
    if not cols:
        return None
    fig = _figure(10.0, 3.6, right=_legend_right(len(cols)), left=0.8)
    ax = fig.subplots()
    for n, j in enumerate(cols):
        v = np.where(V[:, j] > 0, V[:, j], np.nan)
        ax.semilogy(k, v, lw=1.1, marker=_marker(len(k)), ms=2.5, label=ctx.names[j],
                    **line_style(n))
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("variance [SI units\u00b2]", fontsize=8)
    _style(ax, iterations=True)
    ax.legend(fontsize=7, ncol=_legend_columns(len(cols)), loc="upper left",
              bbox_to_anchor=(1.01, 1.0), frameon=False)
    return _img(fig, "variance per iteration",
                "Variance of each calibrated parameter per iteration, Var(e(k)) (eq. 52; "
                "report Fig. 11, 29). Gaps: the parameter was not calibrated in that iteration.")


@_styled(8)
def _fig_condition(ctx, hist) -> str:
    c = np.array([float(h.condition_number) for h in hist])
    k = np.arange(1, len(hist) + 1)
    ok = np.isfinite(c) & (c > 0)
    if not ok.any():
        return None
    fig = _figure(10.0, 2.8, right=1.7, left=0.8)
    ax = fig.subplots()
    ax.plot(k[ok], c[ok], color="#1f77b4", lw=1.2, marker=_marker(len(k)), ms=2.5)
    if c[ok].max() / c[ok].min() > 10:
        ax.set_yscale("log")
    else:
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    if finite(ctx.res.condition_number) and ctx.res.condition_number > 0:
        ax.axhline(ctx.res.condition_number, color="#d62728", lw=0.8, ls="--")
        ax.text(k[-1], ctx.res.condition_number,
                f" at the solution {ctx.res.condition_number:.4g}", va="bottom", ha="right",
                fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("condition number", fontsize=8)
    _style(ax, iterations=True)
    return _img(fig, "condition number per iteration",
                "Condition number of the scaled, weighted observation matrix per iteration "
                "(report Fig. 12, 30).")


@_styled(7)
def _fig_residuals(ctx) -> str:
    chans = list(enumerate(ctx.channels))
    if not chans or ctx.after.size == 0:
        return None
    has_before = ctx.before is not None
    ncol = 3 if has_before else 2
    fig = _figure(10.0, 2.2 * len(chans) + 0.4, left=0.8, bottom=0.55, top=0.3,
                  wspace=0.3, hspace=0.6)
    axes = fig.subplots(len(chans), ncol, squeeze=False)
    for row, (c, ch) in enumerate(chans):
        si = ctx.channel_unit[ch]
        sel = ctx.rows_of(c)
        s = ctx.res.sigma.get(ch)
        s = float(s) if finite(s) and s > 0 else 0.0
        after = ctx.after[sel]
        unit, f = ctx.display.unit(si)
        a = after * f
        sf = s * f
        i = np.arange(a.size)
        col = 0
        if has_before:
            b = ctx.before[sel] * f
            ax = axes[row][col]
            ax.vlines(i, 0, b, color="#7f7f7f", lw=1.0)
            ax.plot(i, b, "o", color="#7f7f7f", ms=2.5)
            ax.axhline(0, color="k", lw=0.6)
            _title(ax, f"{ch}: before (start values)")
            ax.set_ylabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
            _style(ax, nbins=4)
            col += 1
        ax = axes[row][col]
        ax.vlines(i, 0, a, color="#1f77b4", lw=1.0)
        ax.plot(i, a, "o", color="#1f77b4", ms=2.5)
        ax.axhline(0, color="k", lw=0.6)
        if sf > 0:
            for sgn in (-1, 1):
                ax.axhline(sgn * sf, color="#d62728", lw=0.7, ls="--")
        _title(ax, f"{ch}: after (calibrated)")
        ax.set_ylabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        _style(ax, nbins=4)
        ax = axes[row][col + 1]
        nb = int(min(30, max(8, math.sqrt(max(a.size, 1)) * 1.5)))
        lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
        if sf > 0:
            lo, hi = min(lo, -3 * sf), max(hi, 3 * sf)
        if not hi > lo:
            lo, hi = lo - 0.5, hi + 0.5
        edges = np.linspace(lo, hi, nb + 1)
        ax.hist(a, bins=edges, color="#1f77b4", alpha=0.75, edgecolor="white", linewidth=0.5)
        if sf > 0 and a.size > 1:
            xs = np.linspace(lo, hi, 200)
            pdf = np.exp(-0.5 * (xs / sf) ** 2) / (sf * math.sqrt(2 * math.pi))
            ax.plot(xs, pdf * a.size * float(edges[1] - edges[0]), color="#d62728", lw=1.0)
        _title(ax, f"{ch}: after, histogram")
        ax.set_xlabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        _style(ax, nbins=4)
        for ax in axes[row]:
            ax.ticklabel_format(useOffset=False, style="sci", scilimits=(-3, 4))
            ax.xaxis.get_offset_text().set_fontsize(7)
            ax.yaxis.get_offset_text().set_fontsize(7)
    for ax in axes[-1][: ncol - 1]:
        ax.set_xlabel("row (pose order)", fontsize=8)
    return _img(fig, "residuals per channel before and after calibration",
                "Residuals (measured \u2212 predicted) per channel, by row in pose order: at the "
                "start values, at the calibrated values (dashed: \u00b1 sigma used), and the "
                "histogram after calibration with the normal density of that sigma.")



def validation_figure(rows, units):
    """The held-out errors per channel as a matplotlib Figure: RMS and max before and
    after, on a log axis so that "after" (often 1000 times smaller) stays visible;
    None when no row has an "after" value. ``rows`` as :func:`station.fitting.validation.
    validation_errors` gives them (SI, with their unit), shown in ``units``."""
    good = [v for v in rows if finite(v.get("rms_after")) and finite(v.get("max_after"))]
    if not good:
        return None
    ncol = min(4, len(good))
    nrow = math.ceil(len(good) / ncol)
    fig = _figure(2.6 * ncol + 0.4, 2.4 * nrow + 0.3, left=0.7, bottom=0.35, top=0.6,
                  wspace=0.45, hspace=0.5)
    for n, (ax, v) in enumerate(zip(_panels(fig, len(good), ncol), good)):
        label, f = units.unit(str(v.get("unit") or ""))
        vals = {when: [float(v[f"{what}_{when}"]) * f if finite(v.get(f"{what}_{when}"))
                       else float("nan") for what in ("rms", "max")]
                for when in ("before", "after")}
        shown = [abs(x) for xs in vals.values() for x in xs if math.isfinite(x) and x != 0]
        # bars rise from a decade below the smallest value: each has a visible height
        floor = 10.0 ** math.floor(math.log10(min(shown)) - 1) if shown else 1e-12
        top = max(shown) if shown else 1.0
        pos = np.arange(2)
        for dx, when, color in ((-0.2, "before", "#7f7f7f"), (0.2, "after", "#1f77b4")):
            heights = vals[when]
            if not any(math.isfinite(x) for x in heights):
                continue
            h = [max(abs(x), floor * 1.5) - floor if math.isfinite(x) else 0.0
                 for x in heights]
            bars = ax.bar(pos + dx, h, 0.4, bottom=floor, color=color, label=when)
            ax.bar_label(bars, labels=[format(x, ".3g") if math.isfinite(x) else "n/a"
                                       for x in heights], fontsize=6, padding=1)
        ax.set_yscale("log")
        ax.set_ylim(floor, top * 8)
        ax.set_xticks(pos, ["RMS", "max"])
        _title(ax, f"{v.get('channel')}" + (f" [{label}]" if label else ""))
        _style(ax, 7, minor=False)
        if n == 0:
            fig.legend(*ax.get_legend_handles_labels(), fontsize=7, frameon=False,
                       loc="upper right", ncol=2)      # above the titles, not on them
    return fig


@_styled(7)
def fig_validation(rows, units) -> dict | None:
    fig = validation_figure(rows, units)
    if fig is None:
        return None
    return _img(fig, "validation error before and after calibration",
                "Held-out poses: RMS and maximum error per channel before (start values) "
                "and after calibration (log scale: each bar's label is its value).")
