"""What a results file answers, first: findings as sentences, each with the numbers behind it.

The report opens with these. Each ``Finding`` is a sentence, the anchor of the table or figure on the
report's page that shows it, and its evidence: the numbers it states, by name, so that tests check a
sentence against known values rather than its wording. No finding claims more than the file holds:

- engines (``simrun.findings.engines``), first where a file has them: per engine, each of its integrators' energy
  change per period at h w = 0.1 and 1 and where it grows, from its probed amplification matrix;
- stability: per integrator, the largest dt that ran to its end without diverging and the smallest
  that diverged (measured: only from runs at those dts), beside the predicted limit (runs on the
  undamped test equation only: the limit is a property of the method on q'' + w^2 q = 0);
- artificial damping: the energy a method gains or loses per period T = 2 pi / w at the sweep's h w,
  predicted from the probed amplification matrix (test equation only): per step the energy scales by
  rho^2 and a period is 2 pi / (h w) steps, so the fraction lost per period is
  1 - rho^(4 pi / (h w)) = 1 - exp(-2 pi d_method / w); and how the measured damping agrees with it;
- accuracy and cost: rankings only among runs that reached their end with a known error (exact
  solution, or a reference), by the wall time of the cheapest run within an error budget;
- equal error (``simrun.findings.peers``): simrun's Radau IIA against scipy's Radau on a sweep of
  step_control.tolerance, each one's wall time, steps, Jacobians and factorisations interpolated at the errors both
  reach, and their ratios (runs that did not end ok left out, and named);
- cost at equal dt (sweeps of solver.type; ``simrun.findings.cost``): every method's wall time per 1/60 s
  frame and real-time factor beside its error (or energy change) and its distance from the fastest
  implicit run whose every step converged, Newton's when there is one (what a real-time method, an
  iterative solver on a budget or XPBD, costs against a converged Newton solve);
- what could not be measured, and why, said once.

One module per topic: ``integrators`` (stability, damping, accuracy, orders, energy, what was not measured),
``contact``, ``cost``, ``peers``, ``engines``, ``damping_map`` and ``calibration`` (``simrun fit``), each on the wording of
``base``. The numbers come from ``simrun.analysis.oscillator`` (the rows of ``analysis.rows``, read from the file through
``analysis.runs.run_set``); the findings only select, compare and word them.
"""

from __future__ import annotations

from collections import Counter

from simrun.analysis.rows import OrderRow, SummaryRow, order_rows, summary_rows
from simrun.analysis.runs import RunSet, predictions_for, test_equation_runs
from simrun.findings.base import Finding
from simrun.findings.contact import contact_findings
from simrun.findings.cost import solver_cost
from simrun.findings.damping_map import map_findings
from simrun.findings.engines import engine_findings
from simrun.findings.integrators import (accuracy_findings, damping_budget_findings, damping_findings, energy_findings,
                                         largest_dt_findings, measured_damping_findings, measured_only_findings,
                                         not_measured_findings,
                                         order_findings, stability_findings)
from simrun.findings.peers import peer_findings


def findings(data: RunSet, rows: list[SummaryRow] | None = None, orders: list[OrderRow] | None = None
             ) -> list[Finding]:
    """The findings of a file's runs, in reading order (engines, a damping map's, stability, contact, damping,
    accuracy, equal error, cost, energy, not measured)."""
    rows = summary_rows(data) if rows is None else rows
    orders = order_rows(data) if orders is None else orders
    predictions = predictions_for(data) if test_equation_runs(data) else {}
    several = len(data.groups) > 1

    # the engines' integrators are the question of a file that has them; a map answers its own question first otherwise
    result = engine_findings(data, predictions)
    result += map_findings(data)
    result += stability_findings(data, rows, predictions, several)
    result += contact_findings(rows, several)
    result += largest_dt_findings(data, several)
    result += damping_findings(data, predictions, several)
    result += measured_damping_findings(rows)
    result += measured_only_findings(rows)
    result += damping_budget_findings(data, predictions)
    result += accuracy_findings(data, several)
    result += order_findings(orders, several)
    result += peer_findings(data)
    result += solver_cost(data, rows)
    if not predictions:
        result += energy_findings(data, rows, several)
    result += not_measured_findings(data, orders, several)
    return _at_most_per_kind(result)


# findings of one kind beyond this many are counted, not listed: a map (10^4 runs over hundreds of settings) would
# otherwise say the same of every setting
MAX_PER_KIND = 8


def _at_most_per_kind(found: list[Finding]) -> list[Finding]:
    """The first MAX_PER_KIND findings of each topic, in reading order, each topic's count of the rest after them."""
    counts = Counter(finding.topic for finding in found)
    kept, seen = [], Counter()
    for finding in found:
        seen[finding.topic] += 1
        if seen[finding.topic] <= MAX_PER_KIND:
            kept.append(finding)
        if seen[finding.topic] == MAX_PER_KIND and counts[finding.topic] > MAX_PER_KIND:
            left = counts[finding.topic] - MAX_PER_KIND
            kept.append(Finding(f"… and {left} more {finding.topic} findings of this kind, for other settings of the "
                                "swept keys: the tables and figures show every run.", finding.link_anchor, {"more": left},
                                finding.topic))
    return kept


__all__ = ["Finding", "findings"]
