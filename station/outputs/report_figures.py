"""The report's figures (station/outputs/report.py): matplotlib on its own canvas (pyplot
and its global state are not used), each returned as ``{"src", "alt", "caption"}``
with the SVG embedded as a base64 data URI.

Parameters are plotted in SI (as in the parameter file), residuals and validation
errors in the display units of :mod:`station.outputs.units` (mm and degrees by default).
"""
from __future__ import annotations

import math

import numpy as np

from station.outputs import report_plotting as kit


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


def parameter_panels(n: int) -> list[range]:
    """The parameters figure's panels: the identifiable parameters in table order, at
    most 4 lines per panel up to 16 parameters, at most 6 panels beyond; filled in turn
    (AGEBOT's 14: offsets, gains, lengths, the rest), evenly where the last panel would
    keep less than half a panel (17: 3, 4, 3, 4, 3)."""
    panels = math.ceil(n / max(4, math.ceil(n / 6)))
    per = math.ceil(n / panels)
    if 2 * (n - per * (panels - 1)) >= per:
        cut = [min(n, per * p) for p in range(panels + 1)]
    else:
        cut = [round(n * p / panels) for p in range(panels + 1)]
    return [range(a, b) for a, b in zip(cut, cut[1:])]


def normalised_path(xs, x_final):
    """A parameter's path ``xs`` (iterations 0..K) as ``(xs - x_final) / D``, D its
    largest distance from ``x_final`` (the path's span, so that every path fits in
    [-1, 1]); D = 0 (never moved): zeros. Returns (path, D)."""
    d = np.asarray(xs, dtype=float) - x_final
    big = float(np.max(np.abs(d))) if d.size else 0.0
    return (d / big if big > 0 else np.zeros_like(d)), big


@kit.styled(7)
def _fig_parameters(ctx, hist) -> str:
    idx = _active(ctx)
    if not idx:
        return None
    k, X = _series(ctx, hist)
    groups = parameter_panels(len(idx))
    ncol = min(2, len(groups))
    nrow = math.ceil(len(groups) / ncol)
    legend, left = 1.9, 0.75                # inches: a legend right of each panel
    width = 10.0 if ncol == 2 else 5.0
    panel = (width - left - ncol * legend) / ncol
    fig = kit.figure(width, 2.1 * nrow + 0.55, left=left, bottom=0.5, top=0.25, right=legend,
                     wspace=legend / panel, hspace=0.3)
    axes = fig.subplots(nrow, ncol, squeeze=False, sharex=True, sharey=True)
    ticks = np.array([-1.0, 0.0, 1.0])
    for g, group in enumerate(groups):
        ax = axes[g // ncol][g % ncol]
        ax.axhline(0.0, color="k", lw=0.7, ls="--")
        for n, a in enumerate(group):
            j = idx[a]
            y, big = normalised_path(X[:, j], ctx.x[j])
            unit = ctx.units.get(ctx.names[j], "")
            ax.plot(k, y, lw=1.2, marker=kit.marker(len(k)), ms=2.5,
                    label=f"{ctx.names[j]} (1 = {big:.3g}{' ' + unit if unit else ''})",
                    **kit.line_style(n))
        kit.legend(ax, anchor=(1.0, 1.0), handlelength=1.6, borderaxespad=0.2)
    for g in range(len(groups), nrow * ncol):   # an empty cell: iterations read above it
        axes[g // ncol][g % ncol].set_visible(False)
        above = axes[g // ncol - 1][g % ncol]
        above.xaxis.set_tick_params(labelbottom=True)
        above.set_xlabel("iteration k", fontsize=8)
    ax0 = axes[0][0]
    ax0.set_yticks(ticks)
    ax0.set_ylim(-1.12, 1.12)
    kit.style(ax0, iterations=True)
    for row in axes:
        row[0].set_ylabel("(\u03be(k) \u2212 \u03be_final) / D", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("iteration k", fontsize=8)
    return kit.img(fig, "parameter paths per iteration, each scaled by its largest distance",
                   "Calibrated parameters \u03be(k) per iteration (k = 0: start values; report "
                   "Fig. 10, 28), each as its distance from the calibrated value \u03be_final "
                   "divided by D, its largest distance over the iterations (the legend gives D "
                   "in the parameter's unit: \u03be(k) = \u03be_final + D \u00d7 the value "
                   "drawn); 0: the calibrated value. The start and calibrated values are in the "
                   "parameter table, the distance in standard deviations in the next figure.")


@kit.styled(8)
def _fig_deviation(ctx, hist) -> str:
    idx = [j for j in _active(ctx) if kit.finite(ctx.std[j]) and ctx.std[j] > 0]
    if not idx:
        return None
    k, X = _series(ctx, hist)
    fig = kit.figure(10.0, 3.6, right=kit.legend_right(len(idx)), left=0.8)
    ax = fig.subplots()
    floor = 1e-6
    for n, j in enumerate(idx):
        d = np.abs(X[:, j] - ctx.x[j]) / ctx.std[j]
        ax.semilogy(k, np.maximum(d, floor), lw=1.1, marker=kit.marker(len(k)), ms=2.5,
                    label=ctx.names[j], **kit.line_style(n))
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.text(k[-1], 1.0, " 1 std", va="bottom", ha="right", fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("|\u03be(k) \u2212 \u03be_final| / std", fontsize=8)
    ax.set_ylim(bottom=floor / 2)
    kit.style(ax, iterations=True)
    kit.legend(ax, ncol=kit.legend_columns(len(idx)))
    return kit.img(fig, "parameter deviation from the final value in standard deviations",
                f"Convergence: distance of each identifiable parameter from its calibrated value "
                f"in units of its std (values below {floor:g} drawn at {floor:g}).")


@kit.styled(8)
def _fig_variance(ctx, hist) -> str:
    V = np.array([np.asarray(h.variance, dtype=float) for h in hist])
    k = np.arange(1, len(hist) + 1)
    cols = [j for j in range(V.shape[1]) if np.any(np.isfinite(V[:, j]) & (V[:, j] > 0))]
    if not cols:
        return None
    fig = kit.figure(10.0, 3.6, right=kit.legend_right(len(cols)), left=0.8)
    ax = fig.subplots()
    for n, j in enumerate(cols):
        v = np.where(V[:, j] > 0, V[:, j], np.nan)
        ax.semilogy(k, v, lw=1.1, marker=kit.marker(len(k)), ms=2.5, label=ctx.names[j],
                    **kit.line_style(n))
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("variance [SI units\u00b2]", fontsize=8)
    kit.style(ax, iterations=True)
    kit.legend(ax, ncol=kit.legend_columns(len(cols)))
    return kit.img(fig, "variance per iteration",
                "Variance of each calibrated parameter per iteration, Var(e(k)) (eq. 52; "
                "report Fig. 11, 29). Gaps: the parameter was not calibrated in that iteration.")


@kit.styled(8)
def _fig_condition(ctx, hist) -> str:
    c = np.array([float(h.condition_number) for h in hist])
    k = np.arange(1, len(hist) + 1)
    ok = np.isfinite(c) & (c > 0)
    if not ok.any():
        return None
    fig = kit.figure(10.0, 2.8, right=1.7, left=0.8)
    ax = fig.subplots()
    ax.plot(k[ok], c[ok], color="#1f77b4", lw=1.2, marker=kit.marker(len(k)), ms=2.5)
    if c[ok].max() / c[ok].min() > 10:
        ax.set_yscale("log")
    else:
        ax.ticklabel_format(axis="y", useOffset=False, style="plain")
    if kit.finite(ctx.res.condition_number) and ctx.res.condition_number > 0:
        ax.axhline(ctx.res.condition_number, color="#d62728", lw=0.8, ls="--")
        ax.text(k[-1], ctx.res.condition_number,
                f" at the solution {ctx.res.condition_number:.4g}", va="bottom", ha="right",
                fontsize=7)
    ax.set_xlabel("iteration k", fontsize=8)
    ax.set_ylabel("condition number", fontsize=8)
    kit.style(ax, iterations=True)
    if ax.get_yscale() != "log":
        from matplotlib.ticker import MaxNLocator

        ax.yaxis.set_major_locator(MaxNLocator(5))
    return kit.img(fig, "condition number per iteration",
                "Condition number of the scaled, weighted observation matrix per iteration "
                "(report Fig. 12, 30).")


@kit.styled(7)
def _fig_residuals(ctx) -> str:
    chans = list(enumerate(ctx.channels))
    if not chans or ctx.after.size == 0:
        return None
    has_before = ctx.before is not None
    ncol = 3 if has_before else 2
    fig = kit.figure(10.0, 2.2 * len(chans) + 0.4, left=0.8, bottom=0.55, top=0.3,
                  wspace=0.3, hspace=0.6)
    axes = fig.subplots(len(chans), ncol, squeeze=False)
    if len({int(ctx.rows_of(c).sum()) for c, _ in chans}) == 1:   # rows read under the last
        for col in range(ncol - 1):
            for row in range(1, len(chans)):
                axes[row][col].sharex(axes[0][col])
                axes[row - 1][col].xaxis.set_tick_params(labelbottom=False)
    for row, (c, ch) in enumerate(chans):
        si = ctx.channel_unit[ch]
        sel = ctx.rows_of(c)
        s = ctx.res.sigma.get(ch)
        s = float(s) if kit.finite(s) and s > 0 else 0.0
        after = ctx.after[sel]
        unit, f = ctx.display.unit(si)
        a = after * f
        sf = s * f
        i = np.arange(a.size)
        col = 0
        if has_before:
            b = ctx.before[sel] * f
            ax = axes[row][col]
            kit.segments(ax, i, 0, b, color="#7f7f7f", lw=1.0, marker="o", ms=2.5)
            ax.axhline(0, color="k", lw=0.6)
            kit.title(ax, f"{ch}: before (start values)")
            ax.set_ylabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
            kit.style(ax, nbins=4)
            col += 1
        ax = axes[row][col]
        kit.segments(ax, i, 0, a, color="#1f77b4", lw=1.0, marker="o", ms=2.5)
        ax.axhline(0, color="k", lw=0.6)
        if sf > 0:
            for sgn in (-1, 1):
                ax.axhline(sgn * sf, color="#d62728", lw=0.7, ls="--")
        kit.title(ax, f"{ch}: after (calibrated)")
        ax.set_ylabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        kit.style(ax, nbins=4)
        ax = axes[row][col + 1]
        nb = int(min(30, max(8, math.sqrt(max(a.size, 1)) * 1.5)))
        lo, hi = (float(a.min()), float(a.max())) if a.size else (0.0, 0.0)
        if sf > 0:
            lo, hi = min(lo, -3 * sf), max(hi, 3 * sf)
        if not hi > lo:
            lo, hi = lo - 0.5, hi + 0.5
        edges = np.linspace(lo, hi, nb + 1)
        counts = np.histogram(a, bins=edges)[0]
        # one filled step patch and the bins' white borders as one line: the look of
        # ax.hist without a Rectangle artist per bin
        ax.stairs(counts, edges, fill=True, color="#1f77b4", alpha=0.75, lw=0)
        kit.segments(ax, edges[1:-1], 0, np.minimum(counts[:-1], counts[1:]), color="white",
                     lw=0.5)
        if sf > 0 and a.size > 1:
            xs = np.linspace(lo, hi, 200)
            pdf = np.exp(-0.5 * (xs / sf) ** 2) / (sf * math.sqrt(2 * math.pi))
            ax.plot(xs, pdf * a.size * float(edges[1] - edges[0]), color="#d62728", lw=1.0)
        kit.title(ax, f"{ch}: after, histogram")
        ax.set_xlabel(f"residual [{unit}]" if unit else "residual", fontsize=8)
        kit.style(ax, nbins=4)
        for ax in axes[row]:
            ax.ticklabel_format(useOffset=False, style="sci", scilimits=(-3, 4))
            ax.xaxis.get_offset_text().set_fontsize(7)
            ax.yaxis.get_offset_text().set_fontsize(7)
    for ax in axes[-1][: ncol - 1]:
        ax.set_xlabel("row (pose order)", fontsize=8)
    return kit.img(fig, "residuals per channel before and after calibration",
                "Residuals (measured \u2212 predicted) per channel, by row in pose order: at the "
                "start values, at the calibrated values (dashed: \u00b1 sigma used), and the "
                "histogram after calibration with the normal density of that sigma.")



def validation_figure(rows, units):
    """The held-out errors per channel as a matplotlib Figure: RMS and max before and
    after, on a log axis so that "after" (often 1000 times smaller) stays visible;
    None when no row has an "after" value. ``rows`` as :func:`station.fitting.validation.
    validation_errors` gives them (SI, with their unit), shown in ``units``."""
    good = [v for v in rows if kit.finite(v.get("rms_after")) and kit.finite(v.get("max_after"))]
    if not good:
        return None
    from matplotlib.ticker import LogLocator

    ncol = min(4, len(good))
    nrow = math.ceil(len(good) / ncol)
    fig = kit.figure(2.6 * ncol + 0.4, 2.4 * nrow + 0.3, left=0.7, bottom=0.35, top=0.6,
                  wspace=0.45, hspace=0.5)
    for n, (ax, v) in enumerate(zip(kit.panels(fig, len(good), ncol), good)):
        label, f = units.unit(str(v.get("unit") or ""))
        vals = {when: [float(v[f"{what}_{when}"]) * f if kit.finite(v.get(f"{what}_{when}"))
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
        kit.title(ax, f"{v.get('channel')}" + (f" [{label}]" if label else ""))
        kit.style(ax, 7, minor=False)
        ax.yaxis.set_major_locator(LogLocator(numticks=5))   # every decade up to 4
        if n == 0:
            fig.legend(*ax.get_legend_handles_labels(), fontsize=7, frameon=False,
                       loc="upper right", ncol=2)      # above the titles, not on them
    return fig


@kit.styled(7)
def fig_validation(rows, units) -> dict | None:
    fig = validation_figure(rows, units)
    if fig is None:
        return None
    return kit.img(fig, "validation error before and after calibration",
                "Held-out poses: RMS and maximum error per channel before (start values) "
                "and after calibration (log scale: each bar's label is its value).")
