"""How the figures lay runs out: no warning and sane axes when every run diverges, identical curves that stay
visible, one energy reference per run, and x axes that end at the duration.

The runs come from the real pipeline (`simrun CONFIG --no-plots -j 1` into tmp_path), the figures from
``simrun.figures.render_figures``, and each check reads the matplotlib figures themselves.
"""

from __future__ import annotations

import re
import warnings

import matplotlib.pyplot as plt
import numpy as np
import pytest
from matplotlib.lines import Line2D
from matplotlib.text import Text
from mpl_toolkits.mplot3d import Axes3D

from simrun.figures import _layout as layout, figure_data, render_figures
from simrun.results import load
from test_figures import run_pipeline

# Forward Euler on k = 100 N/m, m = 1 kg (w = 10 rad/s) multiplies the energy by 1 + (h w)^2 = 7.25 (dt = 0.25 s)
# or 10 (dt = 0.3 s) per step: both runs pass the divergence bound 1e6 |E0| within ten steps (3 s).
ALL_DIVERGE = {"system": {"type": "spring_mass", "stiffness": 100.0}, "integrators": ["forward_euler"],
               "duration": 3.0, "sweep": {"dt": [0.25, 0.3]}}
# On the linear spring (w = 1 rad/s) backward Euler and its one-Newton-step twin take the same steps, and so do
# BDF2 and the BDF2/midpoint mix at theta = 1 (which is BDF2): two pairs of curves equal to round-off.
TWINS = {"system": {"type": "spring_mass", "stiffness": 1.0}, "duration": 8.0, "sweep": {"dt": [0.1, 0.5, 1.0]},
         "integrators": ["backward_euler", "semi_implicit_backward_euler", "bdf2",
                         {"type": "bdf2_midpoint_mix", "theta": 1.0}, "implicit_midpoint"]}
# A bound orbit (E0 < 0) and a spring (E0 > 0) each have their own E_ref; the axis labels name them.
ORBIT = {"system": {"type": "circular_motion", "force": "gravity"}, "integrators": ["forward_euler", "symplectic_euler"],
         "duration": 3.0, "sweep": {"dt": [0.05, 0.2]}}
# the widest the data's range may be padded on an axis (a decay to 1e-296 is not)
LIMIT_FACTOR = 1e20


def drawn(results_path, folder=None):
    """(name, figure) of every figure of the file, drawn (and saved, which lays them out) with every warning an error."""
    figures = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _, name, figure in render_figures(results_path):
            if folder is not None:
                layout.save_figure(figure, folder / name)
            else:
                figure.canvas.draw()
            figures.append((name, figure))
    return figures


def close(figures) -> None:
    for _, figure in figures:
        plt.close(figure)


def data_values(ax) -> np.ndarray:
    """The finite y values of the lines an axes draws in data coordinates."""
    values = [np.asarray(line.get_ydata(), dtype=float) for line in ax.get_lines()
              if line.get_transform() == ax.transData and len(line.get_ydata())]
    values = np.concatenate(values) if values else np.empty(0)
    return values[np.isfinite(values)]


def plot_axes(figure):
    """The 2-D panels of a figure (not colour bars, not the 3-D snapshots, not the empty slots of a grid)."""
    return [ax for ax in figure.axes if ax.get_visible() and not isinstance(ax, Axes3D) and ax.get_label() != "<colorbar>"]


def test_a_sweep_where_every_run_diverges_draws_every_figure_without_a_warning_and_with_sane_axes(tmp_path):
    results = run_pipeline(tmp_path, "diverge", ALL_DIVERGE)
    assert {run.status for run in load(results).runs.values()} == {"diverged"}
    figures = drawn(results, tmp_path)
    try:
        assert {name for name, _ in figures} >= {"energy_over_time", "energy_drift_vs_dt", "stability_map"}
        for name, figure in figures:
            for ax in plot_axes(figure):
                low, high = sorted(ax.get_ylim())
                assert np.isfinite([low, high]).all(), (name, ax.get_title())
                values = data_values(ax)
                if values.size == 0:
                    continue
                if ax.get_yscale() == "log":
                    positive = values[values > 0]
                    assert low >= positive.min() / LIMIT_FACTOR and high <= positive.max() * LIMIT_FACTOR, \
                        (name, ax.get_title(), (low, high), (positive.min(), positive.max()))
                else:
                    size = max(np.abs(values).max(), 1.0)
                    assert -size * LIMIT_FACTOR <= low and high <= size * LIMIT_FACTOR, (name, ax.get_title(), (low, high))
    finally:
        close(figures)


def lines_of(ax) -> list[Line2D]:
    """The drawn lines of a panel (at least two points, a line style), not markers, guides or legend handles."""
    return [line for line in ax.get_lines() if line.get_visible() and line.get_linestyle() not in ("None", "none", "")
            and len(line.get_xdata()) >= 2 and line.get_transform() == ax.transData]


def same_data(a: Line2D, b: Line2D) -> bool:
    xa, ya = np.asarray(a.get_xdata(), float), np.asarray(a.get_ydata(), float)
    xb, yb = np.asarray(b.get_xdata(), float), np.asarray(b.get_ydata(), float)
    return xa.shape == xb.shape and np.allclose(xa, xb) and np.allclose(ya, yb, rtol=1e-9, atol=1e-12, equal_nan=True)


def legend_texts(figure) -> list[str]:
    legends = list(figure.legends) + [ax.get_legend() for ax in figure.axes if ax.get_legend() is not None]
    return [text.get_text() for legend in legends for text in legend.get_texts()]


def test_identical_curves_are_drawn_once_with_both_names_or_visibly_apart(tmp_path):
    """Backward Euler = semi-implicit backward Euler and BDF2 = the mix at theta = 1 on the linear spring: in every
    panel of every figure, two lines with the same data differ in style (one dashed over the other), and the energy
    figures name both twins in one legend entry (drawn once)."""
    results = run_pipeline(tmp_path, "twins", TWINS)
    figures = drawn(results)
    try:
        for name, figure in figures:
            for ax in plot_axes(figure):
                lines = lines_of(ax)
                for number, line in enumerate(lines):
                    for other in lines[:number]:
                        if same_data(line, other) and line.get_color() != other.get_color():
                            assert (line.get_linestyle(), line.get_linewidth()) != (other.get_linestyle(), other.get_linewidth()), \
                                f"{name}, panel {ax.get_title()!r}: {line.get_label()} hides under {other.get_label()}"
        by_name = dict(figures)
        for name in ("energy_over_time", "energy_drift_vs_dt"):
            texts = legend_texts(by_name[name])
            assert any(re.search(r"\bbackward_euler = semi_implicit_backward_euler\b", text) for text in texts), (name, texts)
            assert any("bdf2 = bdf2_midpoint_mix[theta=1]" in text for text in texts), (name, texts)
    finally:
        close(figures)


def test_energy_is_relative_to_each_runs_stated_reference_and_x_axes_end_at_the_duration(tmp_path):
    """Energy over time plots (E - E0) / E_ref: it starts at 0 for the bound orbit (E0 < 0, E_ref = |E0|) as for the
    spring, the axis label names E_ref, one y scale serves every panel, and time axes end at the duration."""
    results = run_pipeline(tmp_path, "orbit", ORBIT)
    data = figure_data(load(results))
    assert all(run.energy[0] < 0 and run.energy_ref == pytest.approx(abs(run.energy[0])) for run in data.runs)
    figures = drawn(results)
    try:
        figure = dict(figures)["energy_over_time"]
        panels = plot_axes(figure)
        assert len({ax.get_yscale() for ax in panels}) == 1 and len({ax.get_ylim() for ax in panels}) == 1
        for ax in panels:
            assert ax.get_xlim() == pytest.approx((0.0, ORBIT["duration"]))
            for line in lines_of(ax):
                if len(line.get_xdata()) > 2:  # a curve, not the dashed 0 line
                    assert line.get_ydata()[0] == pytest.approx(0.0, abs=1e-12)
        words = [text.get_text() for text in figure.findobj(Text)]
        assert any("E$_{ref}$ = |E0| (initial energy)" in word for word in words), words
    finally:
        close(figures)


def test_the_stability_map_colour_bar_has_ticks_either_side_of_zero(tmp_path):
    results = run_pipeline(tmp_path, "diverge", ALL_DIVERGE)
    figures = drawn(results)
    try:
        figure = dict(figures)["stability_map"]
        (bar,) = [ax for ax in figure.axes if ax.get_label() == "<colorbar>"]
        ticks = [tick for tick in bar.get_yticks() if bar.get_ylim()[0] <= tick <= bar.get_ylim()[1]]
        assert min(ticks) < 0 < max(ticks) and min(ticks) == pytest.approx(-max(ticks))
    finally:
        close(figures)


def test_a_long_panel_title_of_swept_settings_breaks_between_settings():
    """Three swept solver keys side by side ran into the neighbouring panels' titles: a section's title is broken
    after a comma into lines of at most PANEL_TITLE_WIDTH characters (one setting longer than that keeps its line),
    and read back without the breaks it is the one-line title."""
    from simrun.analysis.runs import settings_title
    from simrun.figures._data import PANEL_TITLE_WIDTH
    swept = {"solver.type": "projective_dynamics", "solver.chebyshev_rho": 0.9, "solver.time_budget": 0.002,
             "system.resolution": "x" * (PANEL_TITLE_WIDTH + 5)}
    title = settings_title(swept, width=PANEL_TITLE_WIDTH)
    assert title.split("\n") == ["solver.type = projective_dynamics,", "solver.chebyshev_rho = 0.9,",
                                 "solver.time_budget = 0.002,", "system.resolution = " + "x" * (PANEL_TITLE_WIDTH + 5)]
    assert title.replace("\n", " ") == settings_title(swept)
    assert settings_title({"solver.type": "newton"}, width=PANEL_TITLE_WIDTH) == "solver.type = newton"


def test_one_start_state_has_one_budget_line(tmp_path):
    """slope.yaml (the square on the slope at mu = 0.05 and 0.11, three methods, one start state): each method slides
    its own distance down, so each run's lowest gravity energy differs; the budget counts gravity from one zero for
    every run, and every panel's dashed budget line is the same (it was three different lines)."""
    import simrun
    from pathlib import Path

    config = Path(__file__).resolve().parents[1] / "configs" / "slope.yaml"
    results = simrun.run(config, output=tmp_path / "slope", jobs=1, progress=False, figures=False,
                         overrides=["duration=0.3"])
    lowest = {round(float(np.min(run["gravity_energy"])), 9) for run in results.runs.values()}
    assert len(lowest) > 1  # the runs did slide different distances
    figures = drawn(results.path)
    try:
        ((_, figure),) = [(name, figure) for name, figure in figures if name == "energy_budget"]
        lines = [line for ax in figure.axes for line in ax.get_lines() if line.get_linestyle() == "--"]
        assert len(lines) == len(results.runs)
        levels = np.array([line.get_ydata() for line in lines])
        np.testing.assert_allclose(levels, np.broadcast_to(levels[0], levels.shape), rtol=1e-12)
    finally:
        close(figures)


def test_solver_iterations_are_named_by_solver_and_settings_at_one_dt_told_apart(tmp_path):
    """realtime_solvers.yaml (one dt: each series a point): the iteration figure calls its axis solver iterations and
    names what each solver counts, not "Newton"; L-BFGS's two initial Hessians, drawn as line styles elsewhere, are
    told apart at a single dt by their markers (their fill, where the integrators take the colours and line styles tell
    the settings apart)."""
    import simrun
    from pathlib import Path

    config = Path(__file__).resolve().parents[1] / "configs" / "realtime_solvers.yaml"
    results = simrun.run(config, output=tmp_path / "rt", jobs=1, progress=False, figures=False,
                         overrides=["duration=0.05", "sweep.solver.time_budget=[0.004]", "sweep.solver.chebyshev_rho=[0.0]",
                                    "sweep.system.resolution=[[12, 12]]",
                                    "integrators=[backward_euler, {type: xpbd, substeps: 5}]"])
    figures = drawn(results.path)
    try:
        ((_, figure),) = [(name, figure) for name, figure in figures if name == "newton_iterations_vs_dt"]
        words = " ".join(text.get_text() for text in figure.findobj(Text))
        assert "solver iterations per step" in words and "Newton iterations" not in words
        assert "lbfgs: L-BFGS" in words and "vbd: VBD sweep" in words and "projective_dynamics: local-global" in words
        (lbfgs,) = [ax for ax in figure.axes if "lbfgs" in ax.get_title()]
        points = {(line.get_marker(), line.get_fillstyle(), line.get_color()) for line in lbfgs.get_lines()
                  if line.get_marker() not in ("None", "", None)}
        assert len(points) == 2, points
    finally:
        close(figures)


def test_many_settings_at_one_dt_wrap_into_rows_not_one_tall_column(tmp_path):
    """realtime_solvers.yaml has one dt and a dozen settings: energy over time was one column of 11 panels (870 x
    4950 px); the panels now wrap into rows of at most four, each titled with its setting and dt."""
    import simrun
    from pathlib import Path

    config = Path(__file__).resolve().parents[1] / "configs" / "realtime_solvers.yaml"
    results = simrun.run(config, output=tmp_path / "rt", jobs=1, progress=False, figures=False,
                         overrides=["duration=0.05", "integrators=[backward_euler]", "sweep.system.resolution=[[12, 12]]",
                                    "sweep.solver.time_budget=[0.002, 0.008]"])
    figures = drawn(results.path)
    try:
        ((_, figure),) = [(name, figure) for name, figure in figures if name == "energy_over_time"]
        width, height = figure.get_size_inches()
        columns = {round(ax.get_position().x0, 3) for ax in figure.axes if ax.get_lines()}
        assert len(figure.axes) >= 9 and len(columns) == 4 and height < 1.5 * width, (len(figure.axes), columns)
        titles = [ax.get_title() for ax in figure.axes if ax.get_lines()]
        assert all("dt = 0.0167 s" in title and "solver.type = " in title for title in titles), titles
    finally:
        close(figures)


def test_measured_contours_stay_visible_where_the_predicted_ones_lie_on_them(tmp_path):
    """The damping map draws each method's measured contours as white bands under the predicted black dashes, wider
    than them: where the two coincide (every implicit method here, to round-off) both show. The legend says so, and
    so does the shipped config's comment it answers to."""
    from matplotlib.collections import Collection
    from matplotlib.colors import to_rgba
    from pathlib import Path

    import simrun

    config = {"name": "map", "system": {"type": "spring_mass", "mass": 1.0, "damping_ratio": 0.0, "x0": 1.0},
              "integrators": ["backward_euler", "bdf2"], "duration": 4.0,
              "sweep": {"dt": [0.01], "system.stiffness": {"logspace": [0.0, 4.0, 8]},
                        "system.damping_ratio": {"linspace": [0.0, 0.9, 6]}}}
    results = simrun.run(config, output=tmp_path / "map", jobs=1, progress=False, figures=False)
    figures = drawn(results.path)
    try:
        ((_, figure),) = [(name, figure) for name, figure in figures if name == "damping_map"]
        panels = [ax for ax in figure.axes if ax.get_title().split("\n")[0] in ("backward_euler", "bdf2")]
        assert len(panels) == 2
        for ax in panels:
            sets = [item for item in ax.findobj(Collection) if hasattr(item, "levels")]
            white = [item for item in sets if np.allclose(item.get_edgecolor()[0], to_rgba("w"))]
            black = [item for item in sets if np.allclose(item.get_edgecolor()[0], to_rgba("k"))]
            assert white and black
            assert min(item.get_linewidth()[0] for item in white) > 2 * max(item.get_linewidth()[0] for item in black)
            assert max(item.get_zorder() for item in white) < min(item.get_zorder() for item in black)
        legend = " ".join(text.get_text() for text in figure.legends[0].get_texts())
        assert "measured (white band)" in legend and "on the white band where they agree" in legend
    finally:
        close(figures)
    comment = (Path(__file__).resolve().parents[1] / "configs" / "damping_map.yaml").read_text()
    assert "measured contours (white bands) under the predicted ones (black dashes)" in comment


def test_step_controlled_runs_get_a_panel_per_tolerance_not_per_mean_step(tmp_path):
    """A step-controlled run's dt is only its mean accepted step, different for every method at one tolerance: the
    small multiples (energy over time) had a panel per mean step, six of 28 "time steps", each with one method. Now
    a column per tolerance, every method of that tolerance in it."""
    path = run_pipeline(tmp_path, "controlled", {
        "system": {"type": "spring_mass", "stiffness": 100.0, "mass": 1.0, "x0": 1.0},
        "integrators": ["dopri5", "radau_iia", "trbdf2"], "duration": 1.0,
        "step_control": {"tolerance": 1e-4}, "sweep": {"step_control.tolerance": [1e-3, 1e-5]}})
    data = figure_data(load(path))
    rows, notes = layout.dt_grid(data)
    panels = layout.flatten(rows)
    assert [panel.title for panel in panels] == ["tol = 1e-05", "tol = 0.001"] and not notes
    for panel, tolerance in zip(panels, (1e-5, 1e-3)):
        assert len(panel.runs) == 3 and all(run.tolerance == tolerance for run in panel.runs)
