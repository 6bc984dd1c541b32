"""The colour and marker of each integrator label, shared by every figure (and by the data layer, which gives each
line its style)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")  # headless: figures are files, never windows
# the ids of an SVG's elements are hashes salted with a random uuid unless this is set: with it, the same figure
# gives the same SVG in every process (a redraw, a worker of `simrun plot -j N`)
matplotlib.rcParams["svg.hashsalt"] = "simrun"
import matplotlib.pyplot as plt  # noqa: E402


# A marker per integrator label in the figures against dt, so that coinciding lines stay apart
# (and colour is not the only cue); "X" is kept for failed runs.
LABEL_MARKERS = "osD^vP<>hpd*"


# -- colours, markers, saving ----------------------------------------------------------------------
def label_colours(labels: list[str]) -> dict[str, tuple]:
    """A stable colour per integrator label: sorted labels -> tab10 (or tab20 beyond ten labels)."""
    ordered = sorted(labels)
    if len(ordered) <= 10:
        palette = plt.get_cmap("tab10")
        return {label: palette(number) for number, label in enumerate(ordered)}
    # tab20 pairs a dark and a light shade of each hue: all dark ones first, so that neighbours differ in hue
    palette = plt.get_cmap("tab20")
    shades = [palette(index) for index in (*range(0, 20, 2), *range(1, 20, 2))]
    return {label: shades[number % len(shades)] for number, label in enumerate(ordered)}


def label_markers(labels: list[str]) -> dict[str, str]:
    """A marker per label, in the labels' order."""
    return {label: LABEL_MARKERS[number % len(LABEL_MARKERS)] for number, label in enumerate(labels)}
