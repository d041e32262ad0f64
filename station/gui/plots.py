"""Plots (matplotlib's Qt canvas): the calibration's convergence, live, and the
planned poses in the workspace."""
from __future__ import annotations

import math

import numpy as np
from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from PySide6.QtCore import QSize, QTimer
from PySide6.QtWidgets import QSizePolicy

COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf", "#393b79", "#637939", "#843c39", "#7b4173",
          "#3182bd", "#e6550d")


class Canvas(FigureCanvasQTAgg):
    """A figure in a widget, sized by the layout (``min_height`` pixels at least).

    ``hint``: the size it asks for, ``(width, height)``; by default matplotlib's, the
    figure's default size (614 x 460 px): a page that scrolls lays out at the hint's
    height, so a picture that should fit on the page with what is under it gives a
    smaller one (it still grows into the room the page has)."""

    def __init__(self, min_height: int = 220, parent=None, hint=None):
        self.figure = Figure(dpi=96, layout="constrained")
        super().__init__(self.figure)
        self.setParent(parent)
        self.setMinimumHeight(min_height)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self._hint = None if hint is None else QSize(*hint)

    def sizeHint(self) -> QSize:
        return self._hint if self._hint is not None else super().sizeHint()

    def wheelEvent(self, event) -> None:
        """The wheel scrolls the page the plot is on (the plots do not zoom)."""
        from station.gui.widgets import wheel_to_page

        wheel_to_page(self, event)


def _style(ax, title: str, ylabel: str = "") -> None:
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("iteration k", fontsize=8)
    if ylabel:
        ax.set_ylabel(ylabel, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(True, alpha=0.3, lw=0.5)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


class ConvergencePlots(Canvas):
    """Three plots filled while Algorithm 2 iterates: each parameter's step in
    units of its std (convergence), each parameter's variance (eq. 52) and the
    condition number of the scaled, weighted observation matrix."""

    def __init__(self, parent=None):
        super().__init__(230, parent)
        self.setMaximumHeight(300)
        self.history: list = []
        self.names: tuple[str, ...] = ()
        self.x0 = None
        self._pending = False
        self.draws = 0
        self.reset()

    def reset(self, x0=None) -> None:
        self.history, self.names, self.x0 = [], (), None if x0 is None else np.asarray(x0)
        self.final_condition = None     # the result's, at the solution (the page's text)
        self._draw()

    def add(self, iteration) -> None:
        """One solver iteration (any thread's signal, delivered on the GUI thread)."""
        self.history.append(iteration)
        if not self._pending:           # at most ~8 redraws a second
            self._pending = True
            QTimer.singleShot(120, self._draw)

    def finish(self, result, x0=None) -> None:
        """The final result: its whole history, with the parameter names."""
        self.history = list(result.history)
        self.names = tuple(result.names)
        self.final_condition = result.condition_number
        self.x0 = np.asarray(x0 if x0 is not None else getattr(result, "x0", None), dtype=float)
        self._draw()

    def _draw(self) -> None:
        self._pending = False
        self.draws += 1
        fig = self.figure
        fig.clear()
        a1, a2, a3 = fig.subplots(1, 3)
        h = self.history
        _style(a1, "convergence: |step| / std", "parameter step / std")
        _style(a2, "variance of each parameter", "variance [SI\u00b2]")
        _style(a3, "condition number", "")
        if h:
            X = np.array([np.asarray(it.x, dtype=float) for it in h])
            V = np.array([np.asarray(it.variance, dtype=float) for it in h])
            start = self.x0 if self.x0 is not None and self.x0.shape == X[0].shape else X[0]
            prev = np.vstack([start, X[:-1]])
            k = np.arange(1, len(h) + 1)
            with np.errstate(invalid="ignore", divide="ignore"):
                S = np.abs(X - prev) / np.sqrt(V)
            lines = []
            from station.outputs.report_plotting import line_style

            for j in range(X.shape[1]):
                st = line_style(j)          # every parameter its own colour or dash
                s = np.where(np.isfinite(S[:, j]) & (S[:, j] > 0), S[:, j], np.nan)
                v = np.where(np.isfinite(V[:, j]) & (V[:, j] > 0), V[:, j], np.nan)
                if np.isfinite(s).any():
                    a1.semilogy(k, np.maximum(s, 1e-6), lw=1.1, marker=".", ms=3, **st)
                if np.isfinite(v).any():
                    (ln,) = a2.semilogy(k, v, lw=1.1, marker=".", ms=3, **st)
                    lines.append((ln, self.names[j] if j < len(self.names) else f"#{j + 1}"))
            a1.axhline(1.0, color="k", lw=0.7, ls="--")
            cond = np.array([float(it.condition_number) for it in h])
            ok = np.isfinite(cond) & (cond > 0)
            if ok.any():
                a3.plot(k[ok], cond[ok], color="#1f77b4", lw=1.2, marker=".", ms=4)
                if cond[ok].max() / cond[ok].min() > 10:
                    a3.set_yscale("log")
                final = self.final_condition
                if final is not None and math.isfinite(final) and final > 0:
                    # the one value the page states: at the solution (after the last step)
                    a3.axhline(final, color="#d62728", lw=0.8, ls="--")
                    a3.set_title(f"condition number (at the solution {final:.4g})", fontsize=9)
                else:
                    a3.set_title(f"condition number (iteration {int(k[ok][-1])}: "
                                 f"{cond[ok][-1]:.4g})", fontsize=9)
            if self.names and lines:
                fig.legend([ln for ln, _ in lines], [n for _, n in lines], loc="outside right",
                           fontsize=7, frameon=False, ncol=1 if len(lines) <= 14 else 2)
        else:
            for ax in (a1, a2, a3):
                ax.text(0.5, 0.5, "waiting for the first iteration", ha="center",
                        va="center", fontsize=8, color="#777", transform=ax.transAxes)
        self.draw_idle()


class WorkspacePlot(Canvas):
    """The planned poses in the workspace: SM end-effector positions, PM wrist
    orientations, in the display units (mm, degrees); fit and held-out poses,
    measured filled. A robot file's arm: its tool positions with the arm at the
    reference and the floor (:meth:`show_arm_plan`)."""

    def __init__(self, parent=None):
        super().__init__(260, parent)
        self.count = 0

    def _poses(self, ax, poses, measured, scale: float, at=None) -> None:
        """The poses' tool positions (their targets, or ``at`` ``(m, 3)``), fit and held
        out, measured filled, and the line of travel."""
        measured = set(measured)
        at = np.array([p.target[:3] for p in poses], dtype=float) if at is None else at
        for use, color, name in (("fit", "#1f77b4", "fit"), ("validation", "#ff7f0e", "held out")):
            for done in (False, True):
                P = np.array([x for p, x in zip(poses, at)
                              if p.use == use and (p.index in measured) == done], dtype=float)
                if P.size == 0:
                    continue
                P = P * scale
                ax.scatter(P[:, 0], P[:, 1], P[:, 2], s=28, color=color if done else "none",
                           edgecolors=color, linewidths=1.2,
                           label=f"{name} ({'measured' if done else 'to measure'})")
        if len(poses) > 1:
            T = at * scale
            ax.plot(T[:, 0], T[:, 1], T[:, 2], color="#999", lw=0.6, alpha=0.7)

    @staticmethod
    def _reference(ax, reference, scale: float) -> None:
        r = np.asarray(reference, dtype=float)[:3] * scale
        ax.scatter([r[0]], [r[1]], [r[2]], marker="*", s=120, color="#2ca02c",
                   label="reference", depthshade=False)

    def show_plan(self, poses, robot: str, measured=(), reference=None) -> None:
        fig = self.figure
        fig.clear()
        ax = fig.add_subplot(projection="3d")
        self.count = len(poses)
        from station.gui.widgets import display_units

        u = display_units()
        if robot == "agebot-sm":
            unit, scale = u.unit("m")
            labels = (f"x [{unit}]", f"y [{unit}]", f"z (rail) [{unit}]")
        else:
            unit, scale = u.unit("rad")
            labels = (f"alpha [{unit}]", f"beta [{unit}]", f"gamma [{unit}]")
        self._poses(ax, poses, measured, scale)
        if reference is not None:
            self._reference(ax, reference, scale)
        for setter, lab in zip((ax.set_xlabel, ax.set_ylabel, ax.set_zlabel), labels):
            setter(lab, fontsize=8)
        ax.set_box_aspect(None, zoom=0.88)     # room for the z label beside the box
        ax.tick_params(labelsize=7)
        ax.set_title("planned poses in the workspace (line: order of travel)", fontsize=9)
        if poses:
            ax.legend(fontsize=7, loc="upper left", frameon=False)
        self.draw_idle()

    def show_arm_plan(self, poses, robot, xi, reference_qm=None, measured=(),
                      from_qm: bool = False) -> None:
        """A robot file's plan: the tool origins of the poses (model ``xi``, base frame),
        the reference point with the arm there (grey) and the floor ``z = 0``. ``from_qm``
        (a URDF robot measured by a point instrument, whose targets are in the instrument's
        frame once it is estimated): the tool origins of the poses' actuator values, in
        the base link's frame."""
        from station.gui.arm_drawing import (base_frame, draw_arm, draw_floor, setup_axes,
                                             stick, view_box)
        from station.gui.widgets import display_units

        fig = self.figure
        fig.clear()
        ax = fig.add_subplot(projection="3d")
        ax.view_init(elev=22, azim=-60)
        self.count = len(poses)
        unit, scale = display_units().unit("m")
        xi = base_frame(robot, xi)
        tools = None
        if from_qm and poses:
            tools = robot.frames(np.array([p.qm for p in poses], dtype=float), xi)[:, :3, 3]
        at = reference_qm if reference_qm is not None else (poses[0].qm if poses else None)
        if at is not None:
            lo, hi = view_box(robot, xi, at)
            draw_floor(ax, lo, hi, scale)
            arm = stick(robot, at, xi)
            draw_arm(ax, arm, scale, color="#9e9e9e", alpha=0.8, lw=3.0,
                     label="arm at the reference" if reference_qm is not None else None)
            if reference_qm is not None:
                self._reference(ax, arm.tool[:3, 3], scale)
            setup_axes(ax, lo, hi, scale, unit)
        self._poses(ax, poses, measured, scale, tools)
        ax.set_title("planned tool positions (line: order of travel)", fontsize=9)
        if poses:
            ax.legend(fontsize=7, loc="upper left", frameon=False)
        self.draw_idle()
