"""The calibration's figures (``simrun fit``): the fitted parameters against dt beside their predicted values, the
observed motion against each fit's trajectory, and the transfer of fitted parameters to other integrators.

They read the file's fits (``Results.fits``) and its runs' stored parameters only; the numbers and their grouping
come from ``simrun.findings.calibration`` (imported on first use, like ``simrun.analysis.oscillator`` elsewhere): importing the
figures loads no integrator or system. Each returns None for a file without fits.
"""

from __future__ import annotations

import math

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import Normalize
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.ticker import FuncFormatter

from simrun.figures import _layout as layout
from simrun.figures._data import MAX_LINES, FigureData
from simrun.figures._style import label_colours, label_markers

# A positive parameter whose values span more than this ratio gets a log axis.
LOG_RATIO = 10.0
# A parameter that changes sign and reaches beyond this multiple of its anchor gets a symlog axis (linear around 0
# up to the anchor's decade, so the small deviations near the truth stay visible beside the large ones).
SYMLOG_SPAN = 10.0
# a value below this fraction of its anchor (the truth) counts as 0 when choosing the axis
NEGLIGIBLE = 1e-6
FIT_MARKER_SIZE = 5.0
# observed_vs_fitted shows this fraction of the observed span at its start and at its end: the fit's phase and
# amplitude at the start, and what is left of them at the end (the whole span is a solid band of oscillations).
WINDOW_FRACTION = 0.1
# ... with at most this many observations drawn per window (dots beyond that are a grey smear).
MAX_DOTS = 600
# The y range of a window: the observations' and this fraction of their height above and below; fitted lines that
# leave it are cut at the edge (and named in a note), so that one wild fit does not flatten the others.
EDGE_PAD = 0.12
PANEL_COLUMNS = 3
WINDOW_PANEL_SIZE = (4.2, 2.3)  # in, one integrator: two windows side by side
# The transfer map's colour scale ends at this relative error (x100 %): beyond, the motion is not reproduced at all.
TRANSFER_CEILING = 10.0
TRANSFER_CELL = (0.52, 0.3)  # in per cell
CELL_TEXT_SIZE = 6.5
STATUS_TEXT = {"diverged": "div.", "failed": "fail"}  # a transfer that did not run to its end, in its cell


def _fits(data: FigureData):
    """The file's fits, or None when there are none with values to show."""
    fits = data.results.fits
    if fits is None or fits.table.empty:
        return None
    return fits


def _styles(data: FigureData, labels: list[str]) -> tuple[dict, dict]:
    """Colour and marker per integrator label: the figures' own (from the runs) where they cover every label."""
    if all(label in data.colours for label in labels):
        return data.colours, data.markers
    markers = label_markers(labels)
    return label_colours(labels), markers


def _families(data: FigureData, groups: list[list[str]]) -> list[tuple[str, list[list[str]]]]:
    """(title, groups) per panel column: all together when they fit one panel, else explicit / implicit methods
    (labels without a run: "other methods"), each cut into chunks of at most MAX_LINES."""
    if len(groups) <= MAX_LINES:
        return [("", groups)]
    explicit = {run.label: run.explicit for run in data.runs}
    by_family: dict[str, list[list[str]]] = {}
    for group in groups:
        title = {True: "explicit methods", False: "implicit methods"}.get(explicit.get(group[0]), "other methods")
        by_family.setdefault(title, []).append(group)
    columns = []
    for title, members in by_family.items():
        parts = [members[start:start + MAX_LINES] for start in range(0, len(members), MAX_LINES)]
        columns += [(title + (f" ({number + 1}/{len(parts)})" if len(parts) > 1 else ""), part)
                    for number, part in enumerate(parts)]
    return columns


def _y_scale(ax_row, values: np.ndarray, anchor: float) -> None:
    """One kind of y scale for a row of panels (one parameter; each panel its own range, so that a family close to
    the truth is not flattened by one far from it): log for a positive parameter over a wide range, symlog for
    one that changes sign far beyond its anchor, else linear."""
    values = values[np.isfinite(values)]
    if values.size == 0:
        return
    low, high = float(values.min()), float(values.max())
    reference = abs(anchor) if np.isfinite(anchor) and anchor != 0 else float(np.min(np.abs(values[values != 0]), initial=1.0))
    # values at a bound of 0 (a damping the fit drove to nothing: 1e-30) are 0 to the reader, not decades below it
    at_zero = low >= 0 and low < NEGLIGIBLE * reference
    if low > 0 and high / low > LOG_RATIO and not at_zero:
        for ax in ax_row:
            ax.set_yscale("log")
        return
    if (low < 0 < high or at_zero) and max(abs(low), abs(high)) > SYMLOG_SPAN * reference:
        threshold = 10.0 ** math.floor(math.log10(reference))
        for ax in ax_row:
            ax.set_yscale("symlog", linthresh=threshold, linscale=0.6)
            ax.axhline(0.0, color="0.8", lw=0.6, zorder=0)
        return
    for ax in ax_row:
        ax.ticklabel_format(axis="y", useOffset=False)


def _plain_ticks(axis) -> None:
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))


def fitted_parameters_vs_dt(data: FigureData):
    """Each fitted parameter against dt (a row per parameter, a column per family of methods): the fits with their
    standard errors, the predicted values dashed, the truth (or the exact-solution fit) grey."""
    fits = _fits(data)
    if fits is None:
        return None
    from simrun.findings import calibration as found  # on first use: the figures import no findings

    rows = found.fit_rows(fits)
    shown = [row for row in rows if row.shown]
    if not shown:
        return None
    groups = [group for group in found.same_value_groups(rows) if any(row.label == group[0] for row in shown)]
    colours, markers = _styles(data, found.labels_of(rows))
    columns = _families(data, groups)
    anchors, anchor_name = found.anchor_values(fits)
    frequency = found.spring_frequency(data.results, fits)
    keys = fits.parameters
    grid = [[f"{title}" for title, _ in columns] for _ in keys]
    figure, axes = layout.panel_grid(grid, panel_size=layout.SUMMARY_PANEL_SIZE, sharex=True,
                                     legend_width=layout.FIGURE_LEGEND_WIDTH + 0.8, extra_height=0.5)
    hollow = False
    predicted_drawn = False
    for row_number, key in enumerate(keys):
        ax_row = axes[row_number * len(columns):(row_number + 1) * len(columns)]
        values = []
        for ax, (title, members) in zip(ax_row, columns):
            for number, group in enumerate(members):
                # every fit of the line, the stopped ones as NaN: the line breaks where one is left out
                mine = sorted((row for row in rows if row.label == group[0]), key=lambda row: row.dt)
                dts = np.array([row.dt for row in mine])
                value = np.array([row.values[key] if row.shown else np.nan for row in mine])
                error = np.nan_to_num(np.array([row.stderr[key] for row in mine]), nan=0.0)
                predicted = np.array([row.predicted[key] for row in mine])
                converged = np.array([row.status == "converged" for row in mine])
                late = np.array([row.status == "not_converged" for row in mine])
                colour = colours[group[0]]
                size = max(3.0, FIT_MARKER_SIZE - layout.MARKER_SHRINK * number)
                ax.plot(dts, value, "-", color=colour, lw=1.3, zorder=3)
                for keep, face in ((converged, colour), (late, "white")):
                    if keep.any():
                        ax.errorbar(dts[keep], value[keep], yerr=error[keep], fmt=markers[group[0]], color=colour,
                                    mfc=face, ms=size, capsize=2.0, elinewidth=0.9, ls="none", zorder=4)
                hollow |= bool(late.any())
                finite = np.isfinite(predicted)
                if finite.any():
                    ax.plot(dts[finite], predicted[finite], ls=(0, (4.0, 2.0)), color=colour, lw=1.1, zorder=2)
                    predicted_drawn = True
                values += [value, predicted]
            if key in anchors:
                ax.axhline(anchors[key], color="0.55", lw=2.5, alpha=0.45, zorder=1)
            ax.set_xscale("log")
            ax.grid(True, which="major", alpha=0.3)
            ax.set_title(layout.join_titles(title, key), fontsize=9)
        _y_scale(ax_row, np.concatenate(values + [np.array([anchors.get(key, np.nan)])]), anchors.get(key, math.nan))
        for ax in ax_row:
            layout.tidy_log_axes(ax)
            if ax.get_yscale() == "symlog":
                _plain_ticks(ax.yaxis)
        if frequency and row_number == 0:
            for ax in ax_row:
                top = ax.secondary_xaxis("top", functions=(lambda dt: dt * frequency, lambda hw: hw / frequency))
                top.set_xlabel(f"h w (w = {frequency:.3g} rad/s)", fontsize=8)
                top.tick_params(labelsize=8)
                _plain_ticks(top.xaxis)
        ax_row[0].set_ylabel(found.key_label(key), fontsize=9)
    for ax in axes[-len(columns):]:
        ax.set_xlabel("time step dt (s)", fontsize=9)
        _plain_ticks(ax.xaxis)
    for ax in axes:
        ax.tick_params(labelsize=8)
    handles = [Line2D([], [], color=colours[group[0]], marker=markers[group[0]], ms=layout.LEGEND_MARKER_SIZE, lw=1.3,
                      label=" = ".join(group)) for _, members in columns for group in members]
    handles.append(Line2D([], [], color="0.3", marker="o", ms=layout.LEGEND_MARKER_SIZE, lw=1.3,
                          label="solid: fitted ± standard error"))
    if predicted_drawn:
        handles.append(Line2D([], [], color="0.3", ls=(0, (4.0, 2.0)), lw=1.1, label="dashed: predicted"))
    if anchors:
        handles.append(Line2D([], [], color="0.55", lw=2.5, alpha=0.45,
                              label="truth" if anchor_name == "truth" else "exact-solution fit"))
    if hollow:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="white", mec="0.3", ms=layout.LEGEND_MARKER_SIZE,
                              label="hollow: fit not converged"))
    layout.figure_legend(figure, handles)
    notes = []
    left_out = [row for row in rows if not row.shown]
    if left_out:
        notes.append("left out (no values): " + ", ".join(f"{row.label} at dt = {row.dt:g} s ({row.status})"
                                                          for row in left_out))
    if predicted_drawn:
        notes.append("predicted: the parameters at which the method's own step has the observed motion's eigenvalue "
                     "(its decay and phase per step); missing where no such parameters exist")
    if any(len(group) > 1 for group in groups):
        notes.append("A = B: the same fitted values at every dt (within a tenth of their standard errors), drawn once")
    layout.add_notes(figure, notes)
    what = "fitted parameters against dt"
    if left_out:
        what += f" ({len(left_out)} diverged or failed fits left out)"
    layout.suptitle(figure, data, what)
    return figure


def observed_vs_fitted(data: FigureData):
    """The observed positions (grey dots) and each fit's trajectory at the observation times, a panel per integrator
    (methods with one fitted trajectory share one), a line per dt; the first and last tenth of the observations."""
    fits = _fits(data)
    if fits is None or fits.observed_t.size == 0:
        return None
    from simrun.findings import calibration as found

    rows = found.fit_rows(fits)
    frequency = found.spring_frequency(data.results, fits)
    t = np.asarray(fits.observed_t, dtype=float)
    positions = np.asarray(fits.observed_positions, dtype=float).reshape(t.size, -1)
    shown_dof = int(np.argmax(np.ptp(positions, axis=0))) if positions.shape[1] else 0  # the coordinate that moves most
    observed = positions[:, shown_dof]
    name = str(fits.names[shown_dof]) if fits.names else "x"
    panels: list[tuple[str, list]] = []
    reference = fits.reference
    if reference is not None and reference["status"] not in found.STOPPED:
        panels.append(("exact solution", [reference["fit_id"]]))
    for group in found.same_trajectory_groups(fits, rows):
        mine = sorted((row for row in rows if row.label == group[0] and row.shown), key=lambda row: row.dt)
        if mine:
            panels.append((" = ".join(group), mine))
    if not panels:
        return None
    dts = sorted({row.dt for row in rows if row.shown})
    cmap = plt.get_cmap("viridis")
    dt_colours = {dt: cmap(0.9 * number / max(1, len(dts) - 1)) for number, dt in enumerate(dts)}
    span = t[-1] - t[0]
    windows = [(t[0], t[0] + WINDOW_FRACTION * span), (t[-1] - WINDOW_FRACTION * span, t[-1])]
    count = math.ceil(len(panels) / PANEL_COLUMNS)
    columns = math.ceil(len(panels) / count)
    size = (WINDOW_PANEL_SIZE[0] * columns + layout.FIGURE_LEGEND_WIDTH + 0.6, WINDOW_PANEL_SIZE[1] * count + 1.2)
    figure = plt.figure(figsize=size, layout="constrained")
    cells = figure.subfigures(count, columns, squeeze=False)
    clipped, late = [], False
    for number, cell in enumerate(cells.flat):
        if number >= len(panels):
            continue
        title, members = panels[number]
        cell.suptitle(title, fontsize=9)
        pair = cell.subplots(1, 2)
        for side, (ax, (start, end)) in enumerate(zip(pair, windows)):
            inside = (t >= start) & (t <= end)
            every = max(1, int(np.count_nonzero(inside) // MAX_DOTS))
            ax.plot(t[inside][::every], observed[inside][::every], ".", color="0.6", ms=2.5, zorder=1)
            low, high = float(observed[inside].min()), float(observed[inside].max())
            height = max(high - low, 1e-300)
            for member in members:
                if isinstance(member, str):  # the exact-solution fit
                    line = fits.fitted(member).reshape(t.size, -1)[:, shown_dof]
                    ax.plot(t[inside], line[inside], "-", color="black", lw=1.0, zorder=3)
                    continue
                line = fits.fitted(member.fit_id).reshape(t.size, -1)[:, shown_dof]
                style = "-" if member.status == "converged" else ":"
                late |= style == ":"
                ax.plot(t[inside], line[inside], style, color=dt_colours[member.dt], lw=1.0, zorder=2)
                part = line[inside]
                if np.any(np.isfinite(part) & ((part > high + EDGE_PAD * height) | (part < low - EDGE_PAD * height))):
                    clipped.append(f"{title} at dt = {member.dt:g} s")
            ax.set_ylim(low - EDGE_PAD * height, high + EDGE_PAD * height)
            ax.set_xlim(start, end)
            ax.tick_params(labelsize=7)
            ax.set_title(f"{'first' if side == 0 else 'last'} {end - start:.3g} s", fontsize=7.5, color="0.3")
            if number // columns == count - 1 or number + columns >= len(panels):
                ax.set_xlabel("t (s)", fontsize=8)
        if number % columns == 0:
            pair[0].set_ylabel(f"{name} (m)", fontsize=8)
    handles = [Line2D([], [], ls="none", marker=".", color="0.6", ms=6, label=f"observed {name}")]
    if panels[0][0] == "exact solution":
        handles.append(Line2D([], [], color="black", lw=1.0, label="exact-solution fit"))
    handles += [Line2D([], [], color=dt_colours[dt], lw=1.5,
                       label=f"dt = {dt:g} s" + (f" (h w = {dt * frequency:.3g})" if frequency else "")) for dt in dts]
    if late:
        handles.append(Line2D([], [], color="0.3", ls=":", lw=1.2, label="dotted: fit not converged"))
    layout.figure_legend(figure, handles, title="fitted with")
    notes = []
    if len(fits.names) > 1:
        notes.append(f"{name}: of the {len(fits.names)} observed coordinates ({', '.join(map(str, fits.names))}), the one "
                     "that moves most")
    if clipped:
        shown = list(dict.fromkeys(clipped))
        notes.append("lines leaving the observed range are cut at the panel's edge: " + ", ".join(shown[:6])
                     + (f" and {len(shown) - 6} more" if len(shown) > 6 else ""))
    if any(" = " in title for title, _ in panels):
        notes.append("A = B: the same fitted trajectory at every dt, drawn once")
    left_out = [row for row in rows if not row.shown]
    if left_out:
        notes.append("left out (no trajectory): " + ", ".join(f"{row.label} at dt = {row.dt:g} s ({row.status})"
                                                              for row in left_out))
    layout.add_notes(figure, notes)
    layout.suptitle(figure, data, f"observed {name} and the fitted trajectories")
    return figure


def transfer_errors(data: FigureData):
    """The transfer table as a map: rows the fitted integrators, columns each target (integrator, dt) by the fit's
    dt, coloured by log10 of the relative rms error of the fitted parameters simulated with the target."""
    fits = _fits(data)
    if fits is None:
        return None
    from simrun.findings import calibration as found

    table = found.transfer_table(fits)
    if table is None or not table.rows:
        return None
    labels = list(dict.fromkeys(row.label for row in table.rows))
    dts = sorted({row.dt for row in table.rows if np.isfinite(row.dt)})
    exact = [row for row in table.rows if not np.isfinite(row.dt)]
    width = max(1, len(dts))
    grid = np.full((len(labels), width * len(table.targets)), np.nan)
    texts = []  # (x, line, cell): one text per fit and target, the exact-solution fit's centred on its span
    for row in table.rows:
        line = labels.index(row.label)
        for target, cell in enumerate(row.cells):
            if cell is None:
                continue
            value = cell.relative_error if cell.status == "ok" else np.nan
            if np.isfinite(row.dt):
                place = target * width + dts.index(row.dt)
                grid[line, place] = value
                texts.append((place, line, cell))
            else:  # the exact-solution fit has no dt: it spans its target's columns
                grid[line, target * width:(target + 1) * width] = value
                texts.append((target * width + (width - 1) / 2, line, cell))
    logs = np.log10(np.clip(grid, 1e-300, None))
    finite = logs[np.isfinite(logs)]
    low = math.floor(float(finite.min())) if finite.size else -3.0
    high = min(math.ceil(float(finite.max())) if finite.size else 0.0, math.log10(TRANSFER_CEILING))
    norm = Normalize(vmin=low, vmax=max(high, low + 1))
    cmap = plt.get_cmap("magma_r").with_extremes(bad="0.93", over=plt.get_cmap("magma_r")(1.0))
    size = (2.6 + TRANSFER_CELL[0] * grid.shape[1] + 1.2, 1.6 + TRANSFER_CELL[1] * len(labels) + 0.8)
    figure, ax = plt.subplots(figsize=size, layout="constrained")
    image = ax.imshow(np.ma.masked_invalid(logs), cmap=cmap, norm=norm, aspect="auto", interpolation="nearest")
    boxed = False
    for x, line, cell in texts:
        value = logs[line, int(math.floor(x))]
        shade = "white" if np.isfinite(value) and norm(min(value, norm.vmax)) > 0.55 else "black"
        ax.text(x, line, _cell_text(cell), ha="center", va="center", fontsize=CELL_TEXT_SIZE, color=shade)
    ax.set_yticks(range(len(labels)), labels, fontsize=8)
    ticks = [target * width + column for target in range(len(table.targets)) for column in range(width)]
    ax.set_xticks(ticks, [f"{dt:g}" for _ in table.targets for dt in dts] if dts else ["–"] * len(ticks), fontsize=7)
    ax.set_xticks(np.arange(grid.shape[1] + 1) - 0.5, minor=True)
    ax.set_yticks(np.arange(len(labels) + 1) - 0.5, minor=True)
    ax.grid(which="minor", color="white", lw=0.6)
    ax.tick_params(which="minor", length=0)
    for target in range(1, len(table.targets)):
        ax.axvline(target * width - 0.5, color="black", lw=1.5)
    top = ax.secondary_xaxis("top")
    top.set_xticks([target * width + (width - 1) / 2 for target in range(len(table.targets))],
                   [f"simulated with {integrator}\nat dt = {dt:g} s" for integrator, dt in table.targets], fontsize=8)
    top.tick_params(length=0)
    ax.set_xlabel("dt of the fit (s)", fontsize=9)
    ax.set_ylabel("fitted with", fontsize=9)
    bar = figure.colorbar(image, ax=ax, extend="max" if finite.size and finite.max() > norm.vmax else "neither",
                          shrink=0.8, pad=0.02)
    bar.set_label("relative rms error |x − x_obs|_rms / |x_obs|_rms (log)", fontsize=8)
    bar.set_ticks(np.arange(math.ceil(norm.vmin), math.floor(norm.vmax) + 1))
    bar.ax.yaxis.set_major_formatter(FuncFormatter(lambda value, _: _percent(10.0 ** value)))
    bar.ax.tick_params(labelsize=7)
    for target, (integrator, dt) in enumerate(table.targets):  # a fit run again with its own method and dt
        for row in table.rows:
            if row.label == integrator and np.isfinite(row.dt) and math.isclose(row.dt, dt) and dt in dts:
                place = target * width + dts.index(dt)
                ax.add_patch(Rectangle((place - 0.5, labels.index(row.label) - 0.5), 1, 1, fill=False, ec="#1f9bd6",
                                       lw=2.0, zorder=5))
                boxed = True
    notes = [f"cells: the relative error (as %; ×N from 10x); colours end at {_percent(TRANSFER_CEILING)}"]
    if boxed:
        notes.append("boxed: a fit simulated again with its own integrator and dt")
    if any(cell.status != "ok" for _, _, cell in texts):
        notes.append("div.: the simulation diverged; fail: it failed (a grey cell: no error to show)")
    if exact:
        notes.append("the exact-solution fit has no dt: one value per target, across its columns")
    layout.add_notes(figure, notes)
    layout.suptitle(figure, data, "fitted parameters simulated with other integrators")
    return figure


def _percent(value: float) -> str:
    return f"×{value:g}" if value >= 10 else f"{100 * value:g}%"


def _cell_text(cell) -> str:
    """A transfer cell's short text: "0.4%", "46%", "×15", "×4e82"; the status when it did not run to the end."""
    if cell.status != "ok":
        return STATUS_TEXT.get(cell.status.split(":")[0], "?")
    value = cell.relative_error
    if not np.isfinite(value):
        return "–"
    if value >= 100:
        mantissa, exponent = f"{value:.0e}".split("e")
        return f"×{mantissa}e{int(exponent)}"
    if value >= 10:
        return f"×{value:.0f}"
    return f"{100 * value:.2g}%" if value < 0.1 else f"{100 * value:.0f}%"
