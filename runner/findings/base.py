"""A finding, and the wording every topic shares: names, lists, energies per period and drifts as text."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from simrun.analysis.rows import ROUND_OFF_DAMPING

WALL_TIME_NOISE = 0.1  # wall times closer than this fraction are not ranked (≈): timing noise, runs sharing the cores


@dataclass(frozen=True)
class Finding:
    """One answer of the file: a sentence, where the page shows it, and the numbers it states."""

    sentence: str
    link_anchor: str  # "#stability", "#figure-stability_map", ...: the table or figure that shows it
    evidence: dict = field(default_factory=dict)
    topic: str = ""  # engines | stability | damping | accuracy | equal error | cost | energy | not measured


# -- wording ----------------------------------------------------------------------------------------
def _who(title: str, label: str, several: bool) -> str:
    return f"{label} ({title})" if several and title else label


def _dts(values: list[float]) -> str:
    return ", ".join(f"{value:g}" for value in values) + " s"


# a sentence names at most this many items (a map has hundreds of settings alike): the first ones, and how many more
MAX_NAMED = 12


def _and(items: list[str]) -> str:
    if len(items) > MAX_NAMED:
        return ", ".join(items[:MAX_NAMED]) + f" and {len(items) - MAX_NAMED} more"
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def across_settings(members: list[tuple[str, str]], settings: dict[str, dict]) -> str:
    """Who of a sweep over settings (other swept keys than dt): ``members`` (integrator label, group title) that
    share one sentence, worded across the settings instead of one by one. Labels with the same settings are named
    together; their settings as "at every setting of k1 and k2 (N)" or "at M of N settings (k1 a … b, k2 c … d)".
    ``settings``: each group title's swept values."""
    by_label: dict[str, set[str]] = {}
    for label, title in members:
        by_label.setdefault(label, set()).add(title)
    together: dict[frozenset, list[str]] = {}
    for label, titles in by_label.items():
        together.setdefault(frozenset(titles), []).append(label)
    return "; ".join(f"{_and(labels)} {_settings_text(titles, settings)}" for titles, labels in together.items())


def _settings_text(titles: frozenset, settings: dict[str, dict]) -> str:
    # every key any setting has (an explicit method's settings have no solver keys), in the order first seen
    keys = list(dict.fromkeys(key for setting in settings.values() for key in setting))
    names = " and ".join(keys) if len(keys) < 3 else ", ".join(keys[:-1]) + " and " + keys[-1]
    if len(titles) == len(settings):
        return f"at every setting of {names} ({len(settings):,})"
    if len(titles) == 1:
        (title,) = titles
        return f"at {title}"
    ranges = []
    for key in keys:
        values = [settings[title][key] for title in titles if key in settings.get(title, {})]
        if not values:
            continue
        numbers = [value for value in values if isinstance(value, (int, float)) and not isinstance(value, bool)]
        if len(numbers) == len(values):
            low, high = min(numbers), max(numbers)
            ranges.append(f"{key} {low:.3g}" + (f" … {high:.3g}" if high != low else ""))
        else:
            distinct = list(dict.fromkeys(str(value) for value in values))
            ranges.append(f"{key} {_and(distinct)}")
    return f"at {len(titles):,} of {len(settings):,} settings ({', '.join(ranges)})"


def energy_lost_per_period(damping_over_w: float) -> float:
    """Fraction of the energy lost over one period T = 2 pi / w at the damping rate d = (d/w) w: 1 - exp(-2 pi d/w);
    negative for a gain."""
    return -math.expm1(-2.0 * math.pi * damping_over_w)


def per_period_text(lost: float, damping_over_w: float) -> str:
    """The energy change over a period: "loses 6.09 %", "gains 3 %", "grows × 79", "none (ρ = 1)"."""
    if abs(damping_over_w) < ROUND_OFF_DAMPING:
        return "none (ρ = 1)"
    if lost >= 0:
        percent = 100 * lost
        return "loses > 99.9 %" if percent >= 99.95 else f"loses {percent:.3g} %"
    factor = 1 - lost
    return f"gains {100 * (factor - 1):.3g} %" if factor < 2 else f"grows × {factor:.3g}"


def _per_period_list(hws: list[float], lost: list[float], damping: list[float]) -> str:
    """"loses 6.09 % at h w = 0.01, 17.2 % at 0.03; none (ρ = 1) at 0.1 and 0.3": a verb once per run of the same verb."""
    segments: list[tuple[str, list[str]]] = []
    for hw, fraction, value in zip(hws, lost, damping):
        verb, _, amount = per_period_text(fraction, value).partition(" ")
        if verb == "none":
            verb, amount = "none (ρ = 1)", ""
        at = f"{amount} at {hw:.3g}" if amount else f"{hw:.3g}"
        if segments and segments[-1][0] == verb:
            segments[-1][1].append(at)
        else:
            segments.append((verb, [at]))
    texts = []
    for verb, items in segments:
        items = [items[0].replace(" at ", " at h w = ", 1) if " at " in items[0] else f"at h w = {items[0]}"] + items[1:]
        texts.append(f"{verb} " + (_and(items) if verb.startswith("none") else ", ".join(items)))
    return "; ".join(texts)


def drift_text(drift: float) -> str:
    """An energy change relative to E_ref: "4.26 %", or "2.1e+04 × E_ref" for growth beyond ten times it."""
    if not np.isfinite(drift):
        return "–"
    return f"{100 * drift:.3g} %" if drift < 10 else f"{drift:.3g} × E_ref"
