"""What contact did: the findings of runs of systems with contact (docs/contact.md).

For every run that recorded contact, the smallest signed contact distance over its steps: negative where a
vertex went inside a collider (the penalty allows it, IPC never does), positive where the contact kept a gap;
and where friction acted, how much energy it took. One finding per kind, the deepest penetration first.
"""

from __future__ import annotations

import math

from simrun.analysis.rows import SummaryRow
from simrun.analysis.units import distance_text
from simrun.findings.base import Finding, _and


def contact_findings(rows: list[SummaryRow], several: bool) -> list[Finding]:
    """The penetrations and the kept gaps of the runs with contact, and friction's loss; [] without contact."""
    touched = [row for row in rows if not math.isnan(row.min_contact_distance)]
    if not touched:
        return []
    result = []

    def who(row: SummaryRow) -> str:
        return f"{row.integrator} ({row.group}, dt = {row.dt:g} s)" if several and row.group else f"{row.integrator} (dt = {row.dt:g} s)"

    inside = sorted((row for row in touched if row.min_contact_distance < 0.0), key=lambda row: row.min_contact_distance)
    apart = sorted((row for row in touched if row.min_contact_distance >= 0.0), key=lambda row: row.min_contact_distance)
    measured = "measured: the smallest signed distance of a vertex to a collider over every step"
    if inside:
        listed = _and([f"{who(row)} {distance_text(row.min_contact_distance)}" for row in inside])
        result.append(Finding(f"Penetration ({measured}; negative: inside): {listed}.", "#summary",
                              {"min_contact_distance": {row.run_id: row.min_contact_distance for row in inside}},
                              "contact"))
    if apart:
        listed = _and([f"{who(row)} {distance_text(row.min_contact_distance)}" for row in apart])
        result.append(Finding(f"No penetration ({measured}): {listed}.", "#summary",
                              {"min_contact_distance": {row.run_id: row.min_contact_distance for row in apart}},
                              "contact"))
    rubbed = [row for row in touched if math.isfinite(row.friction_work) and row.friction_work != 0.0]
    if rubbed:
        listed = _and([f"{who(row)} {row.friction_work:.3g} J" for row in sorted(rubbed, key=lambda row: -row.friction_work)])
        result.append(Finding(f"Energy friction took out over the run (measured, the work of the steps' friction forces; "
                              f"negative where a moving collider dragged the model): {listed}.", "#figure-energy_budget",
                              {"friction_work": {row.run_id: row.friction_work for row in rubbed}}, "contact"))
    return result
