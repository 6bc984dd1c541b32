"""What a calibration (``simrun fit``) found: findings as sentences and the tables of fitted values and transfers.

Everything here is read from the file's fits (``Results.fits``, ``simrun.results.fits.FitResults``): each
fit's values, standard errors, predicted values, residual and status, its trajectory at the observation times,
and the transfer table. The anchor of a fitted value is the truth that made synthetic observations, else the
fit with the exact solution (the observed motion's own parameters). The findings say:

- which fits did not converge, diverged or failed;
- which methods recover the anchor within FIT_TOLERANCE in every parameter, and up to which dt;
- where a fitted damping leaves the motion's: below zero (the method damps more than the motion, the fit
  pumps energy in) or above EXCESS_DAMPING times it (the method decays less than the motion, or gains);
- which methods fit one trajectory (on positions alone one model, parametrised differently);
- where the best parameters still leave a residual RESIDUAL_EXCESS times the exact-solution fit's (the noise);
- where fitted and predicted differ by more than PREDICTED_TOLERANCE, and what a prediction from the
  eigenvalue alone leaves out;
- how the fitted parameters transfer to another integrator and dt.

The tables are HTML-free models (``FittedTable``, ``TransferTable``) with their cell texts; ``simrun.report.page``
lays them out. ``key_unit``, ``anchor_values`` and ``spring_frequency`` serve the figures as well.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simrun.findings.base import Finding

FIT_TOLERANCE = 0.01  # a fit "recovers" the anchor when every fitted key is within this fraction of it
PREDICTED_TOLERANCE = 0.05  # fitted and predicted differ beyond this fraction of max(|predicted|, |anchor|)
EXCESS_DAMPING = 2.0  # a fitted damping beyond this multiple of the motion's is stated (the method decays too little)
RESIDUAL_EXCESS = 2.0  # rms residual beyond this multiple of the exact-solution fit's: the method's error is not absorbed
# Two fits with trajectories closer than this fraction of the noise (the exact-solution fit's rms residual, else
# 1e-3 of the observations' rms) fit one trajectory: far below anything the data can tell apart.
SAME_TRAJECTORY = 0.01
TRANSFER_TOLERANCE = 0.05  # a transfer "reproduces" the observations within this relative rms error
MAX_NAMED = 4  # a transfer finding names the fits that reproduce the observations when there are at most this many
STOPPED = ("diverged", "failed")  # fits without values to show
UNITS = {"stiffness": "N/m", "damping": "N s/m", "mass": "kg", "youngs_modulus": "Pa", "poisson_ratio": "1",
         "density": "kg/m^3", "beta": "s", "alpha": "1/s", "coefficient": "N s/m"}
SYMBOLS = {"stiffness": "k", "damping": "d", "mass": "m"}
ANCHOR = "#calibration"
FIGURE = "#figure-fitted_parameters_vs_dt"


# -- keys, anchors, the spring's frequency ----------------------------------------------------------
def key_unit(key: str) -> str:
    """The SI unit of a fitted key from its last word ("system.stiffness.stretch" -> "N/m"); "" when not known."""
    return next((unit for word, unit in UNITS.items() if key.endswith(word)), "")


def key_label(key: str) -> str:
    """The key with its unit, as an axis label: "system.damping (N s/m)", or "system.x0 (unit not known)"."""
    unit = key_unit(key)
    return f"{key} ({unit})" if unit else f"{key} (unit not known)"


def key_symbol(key: str) -> str:
    """A short name for sentences: k, d, m, or the key itself."""
    return next((symbol for word, symbol in SYMBOLS.items() if key.endswith(word)), key)


def anchor_values(fits) -> tuple[dict[str, float], str]:
    """(key -> the value a fit should find, what it is): the truth of synthetic data, else the exact-solution fit."""
    if fits.truth:
        return {key: float(fits.truth[key]) for key in fits.parameters if key in fits.truth}, "truth"
    reference = fits.reference
    if reference is not None and reference["status"] not in STOPPED:
        return {key: float(reference[key]) for key in fits.parameters if np.isfinite(reference[key])}, "exact-solution fit"
    return {}, ""


def spring_frequency(results, fits) -> float | None:
    """w = sqrt(k/m) (rad/s) of the observed motion when the runs are the mass on a spring; None otherwise. A fitted
    k or m comes from the anchor (truth or exact-solution fit; None without one: each run holds its own fitted
    value), one not fitted from a run's stored system parameters."""
    runs = list(results.runs.values())
    if not runs:
        return None
    params = runs[0].system_params
    if params.get("type") != "spring_mass":
        return None
    anchors, _ = anchor_values(fits)
    values = {}
    for name, default in (("stiffness", None), ("mass", 1.0)):
        key = f"system.{name}"
        values[name] = anchors.get(key) if key in fits.parameters else params.get(name, default)
    stiffness, mass = values["stiffness"], values["mass"]
    if stiffness is None or mass is None or not stiffness > 0 or not mass > 0:
        return None
    return math.sqrt(float(stiffness) / float(mass))


# -- number texts -----------------------------------------------------------------------------------
def value_text(value: float, digits: int = 3) -> str:
    """A value with `digits` significant digits and a true minus sign; "–" for NaN."""
    if not np.isfinite(value):
        return "–" if np.isnan(value) else ("∞" if value > 0 else "−∞")
    return f"{value:.{digits}g}".replace("-", "−")


def decimals_for(stderr: float) -> int:
    """Decimals that show a standard error to two significant digits (0 to 8)."""
    if not np.isfinite(stderr) or stderr <= 0:
        return 4
    return int(min(8, max(0, 1 - math.floor(math.log10(stderr)))))


def fixed(value: float, decimals: int) -> str:
    return "–" if not np.isfinite(value) else f"{value:.{decimals}f}".replace("-", "−")


def percent_text(fraction: float) -> str:
    """A relative error as text: "0.40 %", "46 %", "×4.2e+82" beyond 100x; the status when not finite."""
    if not np.isfinite(fraction):
        return "–"
    if fraction >= 100:
        return f"×{fraction:.2g}"
    return f"{100 * fraction:.2g} %" if fraction < 0.1 else f"{100 * fraction:.3g} %"


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


# -- the fits as plain rows -------------------------------------------------------------------------
@dataclass(frozen=True)
class Fit:
    """One fit of the table, as the findings and tables read it."""

    fit_id: str
    label: str
    dt: float
    status: str
    message: str
    rms_residual: float
    values: dict
    stderr: dict
    predicted: dict

    @property
    def shown(self) -> bool:
        return self.status not in STOPPED


def fit_rows(fits) -> list[Fit]:
    """The method fits (not the exact solution), in sweep order."""
    return [_fit(row) for row in fits.method_fits.to_dict("records")]


def _fit(row: dict) -> Fit:
    keys = [key for key in row if f"{key} stderr" in row]
    return Fit(row["fit_id"], row["label"], float(row["dt"]), row["status"], row["message"], float(row["rms_residual"]),
               {key: float(row[key]) for key in keys}, {key: float(row[f"{key} stderr"]) for key in keys},
               {key: float(row[f"{key} predicted"]) for key in keys})


def labels_of(rows: list[Fit]) -> list[str]:
    return list(dict.fromkeys(row.label for row in rows))


def noise_scale(fits) -> float:
    """m: the exact-solution fit's rms residual (the noise, what no parameters can fit), else 1e-3 of the observations' rms."""
    reference = fits.reference
    if reference is not None and reference["status"] not in STOPPED and np.isfinite(reference["rms_residual"]):
        return float(reference["rms_residual"])
    return 1e-3 * float(np.sqrt(np.mean(np.square(fits.observed_positions))))


def same_trajectory_groups(fits, rows: list[Fit] | None = None) -> list[list[str]]:
    """Labels whose fitted trajectories coincide (within SAME_TRAJECTORY of the noise) at every dt both were fitted
    at, in sweep order; every label is in one group (most alone)."""
    rows = fit_rows(fits) if rows is None else rows
    tolerance = SAME_TRAJECTORY * noise_scale(fits)
    return _groups(rows, lambda first, second: _coincide(fits, first, second, tolerance))


def _groups(rows: list[Fit], same) -> list[list[str]]:
    """The labels of ``rows`` in sweep order, grouped with the first earlier label whose fits (dt -> Fit) are the
    ``same``."""
    by_label: dict[str, dict[float, Fit]] = {}
    for row in rows:
        by_label.setdefault(row.label, {})[row.dt] = row
    groups: list[list[str]] = []
    for label in labels_of(rows):
        for group in groups:
            if same(by_label[group[0]], by_label[label]):
                group.append(label)
                break
        else:
            groups.append([label])
    return groups


def _coincide(fits, first: dict[float, Fit], second: dict[float, Fit], tolerance: float) -> bool:
    if set(first) != set(second):
        return False
    for dt, one in first.items():
        other = second[dt]
        if not (one.shown and other.shown):
            return False
        a, b = fits.fitted(one.fit_id), fits.fitted(other.fit_id)
        if a.shape != b.shape or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            return False
        if float(np.max(np.abs(a - b), initial=0.0)) > tolerance:
            return False
    return True


def same_value_groups(rows: list[Fit]) -> list[list[str]]:
    """Labels whose fitted values agree at every dt within a tenth of their standard errors (drawn as one line)."""
    return _groups(rows, _same_values)


def _same_values(first: dict[float, Fit], second: dict[float, Fit]) -> bool:
    if set(first) != set(second):
        return False
    for dt, one in first.items():
        other = second[dt]
        if one.status != other.status:
            return False
        for key, value in one.values.items():
            tolerance = 0.1 * max(one.stderr.get(key, 0.0), other.stderr.get(key, 0.0), 1e-12 * abs(value))
            if not (np.isfinite(value) and abs(value - other.values[key]) <= tolerance
                    or np.isnan(value) and np.isnan(other.values[key])):
                return False
    return True


# -- findings ---------------------------------------------------------------------------------------
def calibration_findings(results) -> list[Finding]:
    """The findings of the file's fits, in reading order; [] when the file holds none."""
    fits = results.fits
    if fits is None or fits.table.empty:
        return []
    rows = fit_rows(fits)
    anchors, anchor_name = anchor_values(fits)
    frequency = spring_frequency(results, fits)

    def where(dt: float) -> str:
        """ "h w = 0.5 (dt = 0.05 s)" on the spring, else "dt = 0.05 s"."""
        return f"h w = {dt * frequency:.3g} (dt = {dt:g} s)" if frequency else f"dt = {dt:g} s"

    result = _statuses(rows, where)
    result += _recovered(fits, rows, anchors, anchor_name, where)
    result += _damping(fits, rows, anchors, where)
    result += _coinciding(fits, rows)
    result += _residuals(fits, rows, where)
    result += _predicted(fits, rows, anchors, where)
    result += _transfers(fits, rows, where)
    return result


def _statuses(rows: list[Fit], where) -> list[Finding]:
    found = []
    for status, words in (("not_converged", "did not converge"), ("diverged", "diverged"), ("failed", "failed")):
        mine = [row for row in rows if row.status == status]
        if mine:
            items = [f"{row.label} at {where(row.dt)}" + (f" — {row.message.rstrip('.')}" if row.message else "")
                     for row in mine]
            shown = ("the figure draws its values hollow" if len(mine) == 1 else "the figure draws their values hollow"
                     ) if status == "not_converged" else "left out of the figures"
            found.append(Finding(f"{len(mine)} of {len(rows)} fits {words} ({shown}): {'; '.join(items)}.", ANCHOR,
                                 {"status": status, "fits": [row.fit_id for row in mine]}, "calibration"))
    return found


def _within(row: Fit, anchors: dict[str, float]) -> bool:
    return row.shown and all(abs(row.values[key] - value) <= FIT_TOLERANCE * abs(value)
                             for key, value in anchors.items() if value != 0 and key in row.values)


def _recovered(fits, rows: list[Fit], anchors: dict[str, float], anchor_name: str, where) -> list[Finding]:
    if not anchors:
        return []
    reach: dict[str, str] = {}
    evidence: dict[str, list[float]] = {}
    for label in labels_of(rows):
        mine = sorted((row for row in rows if row.label == label), key=lambda row: row.dt)
        good = [row.dt for row in mine if _within(row, anchors)]
        evidence[label] = good
        if not good:
            reach[label] = "never"
        elif len(good) == len(mine):
            reach[label] = "at every dt"
        elif good == [row.dt for row in mine[:len(good)]]:
            reach[label] = f"up to {where(good[-1])}"
        else:
            reach[label] = "only at dt = " + ", ".join(f"{dt:g}" for dt in good) + " s"
    named = _and([f"{key_symbol(key)} = {value_text(value, 4)} {key_unit(key)}".strip() for key, value in anchors.items()])
    groups: dict[str, list[str]] = {}
    for label, text in reach.items():
        groups.setdefault(text, []).append(label)
    largest = {text: max((max(evidence[label], default=0.0) for label in labels), default=0.0)
               for text, labels in groups.items()}
    order = sorted(groups, key=lambda text: (text == "never", text != "at every dt", -largest[text]))
    parts = [f"{text}: {_and(labels)}" for text, labels in ((text, groups[text]) for text in order)]
    sentence = (f"Within {100 * FIT_TOLERANCE:g} % of the {anchor_name} ({named}) in every fitted parameter — "
                + "; ".join(parts) + ".")
    return [Finding(sentence, FIGURE, {"within": evidence, "tolerance": FIT_TOLERANCE}, "calibration")]


def _damping(fits, rows: list[Fit], anchors: dict[str, float], where) -> list[Finding]:
    """Fitted damping below zero, or above EXCESS_DAMPING times the motion's: one finding for each, naming every
    method with the dts where it happens; the cases its predicted damping does not share (so the method's eigenvalue
    does not explain them) in a third, put down to its start."""
    found = []
    for key, motion in anchors.items():
        if not key.endswith("damping") or motion <= 0:
            continue
        unit = key_unit(key)
        cases: dict[str, list[tuple[list[str], list[Fit]]]] = {"negative": [], "excess": [], "start": []}
        for group in same_value_groups(rows):
            mine = sorted((row for row in rows if row.label == group[0] and row.shown
                           and np.isfinite(row.values.get(key, math.nan))), key=lambda row: row.dt)
            for beyond, test in (("negative", lambda value: value < 0),
                                 ("excess", lambda value: value > EXCESS_DAMPING * motion)):
                chosen = [row for row in mine if test(row.values[key])]
                # the eigenvalue explains it where the predicted damping is as far out (or there is none)
                explained = [row for row in chosen if not np.isfinite(row.predicted.get(key, math.nan))
                             or test(row.predicted[key])]
                if explained:
                    cases[beyond].append((group, explained))
                if len(explained) < len(chosen):
                    cases["start"].append((group, [row for row in chosen if row not in explained]))
        motion_text = f"{value_text(motion)} {unit}"
        openings = {
            "negative": f"Fitted {key_symbol(key)} below zero where the motion has {motion_text}: the method's own step "
                        "decays the motion faster than observed, so the fit can only match the observed decay by pumping "
                        "energy in — ",
            "excess": f"Fitted {key_symbol(key)} above {EXCESS_DAMPING:g}× the motion's {motion_text}: the method's own "
                      "step decays the motion less than observed (or adds energy), and the fit makes up the difference "
                      "with physical damping — ",
            "start": f"Fitted {key_symbol(key)} below zero or above {EXCESS_DAMPING:g}× the motion's {motion_text} where "
                     "the method's eigenvalue would not need it (predicted in brackets): the fit trades decay against the "
                     "offset of the method's start — "}
        for case, groups in cases.items():
            if not groups:
                continue
            items = [_damping_item(group, chosen, key, where, predicted=case == "start") for group, chosen in groups]
            evidence = {"key": key, "motion": motion, "case": case,
                        "values": {label: {row.dt: row.values[key] for row in chosen}
                                   for group, chosen in groups for label in group}}
            found.append(Finding(openings[case] + "; ".join(items) + ".", FIGURE, evidence, "calibration"))
    return found


def _damping_item(group: list[str], chosen: list[Fit], key: str, where, predicted: bool) -> str:
    """ "backward_euler and semi_implicit_backward_euler: −0.0993 N s/m at h w = 0.05 (dt = 0.005 s) to −13.7 N s/m
    at h w = 2 (dt = 0.2 s)"."""
    unit = key_unit(key)

    def one(row: Fit) -> str:
        extra = f" ({value_text(row.predicted.get(key, math.nan))})" if predicted else ""
        return f"{value_text(row.values[key])}{extra} {unit} at {where(row.dt)}"

    span = one(chosen[0]) if len(chosen) == 1 else f"{one(chosen[0])} to {one(chosen[-1])}"
    if predicted and len(chosen) > 2:
        span = ", ".join(one(row) for row in chosen)
    return f"{_and(group)}: {span}"


def _coinciding(fits, rows: list[Fit]) -> list[Finding]:
    found = []
    values = [group for group in same_value_groups(rows) if len(group) > 1]
    for group in same_trajectory_groups(fits, rows):
        if len(group) < 2:
            continue
        same_values = any(set(group) <= set(other) for other in values)
        if same_values:
            sentence = (f"{_and(group)} find the same values and the same trajectory at every dt: on this system they "
                        "are one method (drawn as one line).")
        else:
            sentence = (f"{_and(group)} fit the same trajectory at every dt (to {SAME_TRAJECTORY:g} of the noise) with "
                        "different values: on the observed positions they are one model, parametrised differently, "
                        "and their fitted values convert into each other.")
        found.append(Finding(sentence, "#figure-observed_vs_fitted", {"labels": group}, "calibration"))
    return found


def _residuals(fits, rows: list[Fit], where) -> list[Finding]:
    noise = noise_scale(fits)
    if fits.reference is None:
        return []
    parts, evidence = [], {}
    for group in same_trajectory_groups(fits, rows):
        mine = sorted((row for row in rows if row.label == group[0] and row.shown), key=lambda row: row.dt)
        over = [row for row in mine if row.rms_residual > RESIDUAL_EXCESS * noise]
        if not over:
            continue
        worst = max(over, key=lambda row: row.rms_residual)
        for label in group:
            evidence[label] = {row.dt: row.rms_residual / noise for row in over}
        text = f"{' = '.join(group)} {over[0].rms_residual / noise:.3g}× at {where(over[0].dt)}"
        parts.append(text + (f" up to {worst.rms_residual / noise:.3g}× at {where(worst.dt)}" if worst is not over[0] else ""))
    if not parts:
        return []
    sentence = (f"The best parameters still miss the observations by more than {RESIDUAL_EXCESS:g}× the exact-solution "
                f"fit's rms residual ({value_text(noise)} m, the noise): " + "; ".join(parts)
                + ". There the method's error is not one a change of parameters can absorb.")
    return [Finding(sentence, "#figure-observed_vs_fitted", {"noise": noise, "ratios": evidence}, "calibration")]


def _predicted(fits, rows: list[Fit], anchors: dict[str, float], where) -> list[Finding]:
    """Where fitted and predicted differ by more than PREDICTED_TOLERANCE: one finding naming them, and why."""
    items, evidence = [], []
    for group in same_value_groups(rows):
        mine = []
        for row in sorted((row for row in rows if row.label == group[0] and row.shown), key=lambda row: row.dt):
            for key, value in row.values.items():
                predicted = row.predicted.get(key, math.nan)
                if not (np.isfinite(value) and np.isfinite(predicted)):
                    continue
                scale = max(abs(predicted), abs(anchors.get(key, 0.0)))
                if scale == 0 or abs(value - predicted) <= PREDICTED_TOLERANCE * scale:
                    continue
                sigmas = abs(value - predicted) / row.stderr[key] if row.stderr.get(key, 0) > 0 else math.inf
                mine.append(f"{key_symbol(key)} = {value_text(value, 4)} against {value_text(predicted, 4)} "
                            f"{key_unit(key)} at {where(row.dt)} ({sigmas:.2g} standard errors)".replace("  ", " "))
                evidence.append({"labels": group, "fit_id": row.fit_id, "key": key, "value": value, "predicted": predicted})
        if mine:
            items.append(f"{_and(group)}: " + ", ".join(mine))
    if not items:
        return []
    sentence = (f"Fitted and predicted differ by more than {100 * PREDICTED_TOLERANCE:g} % — " + "; ".join(items)
                + ". The prediction matches only the eigenvalue (the decay and phase per step); the fit must also match "
                "the start: the initial state projects differently on the method's eigenvectors than on the motion's (a "
                "constant amplitude or phase offset the eigenvalue cannot absorb; a multistep method also starts up and "
                "carries further eigenvalues), and the fit trades a little decay and period against that offset. Many "
                "standard errors apart, the difference is not noise.")
    return [Finding(sentence, FIGURE, {"differences": evidence}, "calibration")]


def _transfers(fits, rows: list[Fit], where) -> list[Finding]:
    table = transfer_table(fits)
    if table is None:
        return []
    found = []
    by_id = {row.fit_id: row for row in rows}
    for column, (integrator, dt) in enumerate(table.targets):
        cells = [(row, row.cells[column]) for row in table.rows]
        method = [(row, cell) for row, cell in cells if row.fit_id in by_id and cell.status == "ok"
                  and np.isfinite(cell.relative_error)]
        if not method:
            continue
        good = [row for row, cell in method if cell.relative_error <= TRANSFER_TOLERANCE]
        parts = [f"Simulated with {integrator} at dt = {dt:g} s"]
        reference = next((cell for row, cell in cells if row.fit_id not in by_id), None)
        if reference is not None and np.isfinite(reference.relative_error):
            parts.append(f", the exact-solution fit's parameters miss the observations by {percent_text(reference.relative_error)} "
                         "(relative rms: the noise and this step's own error)")
        worst_row, worst = max(method, key=lambda pair: pair[1].relative_error)
        few = f" ({_and([f'{row.label} at dt = {row.dt:g} s' for row in good])})" if 0 < len(good) <= MAX_NAMED else ""
        parts.append(f"; {len(good)} of {len(method)} method fits' parameters reproduce them within "
                     f"{100 * TRANSFER_TOLERANCE:g} %{few}; the worst, {worst_row.label}'s at {where(worst_row.dt)}, misses "
                     f"by {percent_text(worst.relative_error)}")
        fitted = by_id[worst_row.fit_id]
        damping = [key for key in fitted.values if key.endswith("damping") and fitted.values[key] < 0]
        if worst.relative_error > 1 and damping:
            parts.append(f" ({key_symbol(damping[0])} = {value_text(fitted.values[damping[0]])} {key_unit(damping[0])}: "
                         "the negative damping makes the motion grow once no method damping cancels it)")
        stopped = [row for row, cell in cells if cell.status != "ok"]
        if stopped:
            parts.append(f"; {len(stopped)} did not run to the end (diverged or failed)")
        found.append(Finding("".join(parts) + ".", "#calibration-transfer",
                             {"target": (integrator, dt), "within": [row.fit_id for row in good],
                              "worst": worst_row.fit_id, "worst_error": worst.relative_error}, "calibration"))
    return found


# -- tables ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class FittedCell:
    value: float
    stderr: float
    predicted: float
    status: str

    def text(self) -> str:
        """ "99.9804 ± 0.0016 (99.8793)": the value, its standard error, and the predicted value when there is one."""
        predicted = self.predicted_text()
        return self.value_text() + (f" ({predicted})" if predicted else "")

    def value_text(self) -> str:
        """ "99.9804 ± 0.0016", to the standard error's second significant digit; the status of a stopped fit."""
        if self.status in STOPPED:
            return self.status
        decimals = decimals_for(self.stderr)
        text = fixed(self.value, decimals)
        return text + (f" ± {fixed(self.stderr, decimals)}" if np.isfinite(self.stderr) else "")

    def predicted_text(self) -> str:
        """The predicted value to as many decimals as the fitted one ("" when there is none)."""
        if self.status in STOPPED or not np.isfinite(self.predicted):
            return ""
        return fixed(self.predicted, decimals_for(self.stderr))


@dataclass(frozen=True)
class FittedTable:
    """One fitted key: rows the integrators, columns the dts (h w on the spring), each cell a FittedCell or None."""

    key: str
    unit: str
    dts: list[float]
    hws: list[float]  # NaN when the runs are not the spring
    rows: list[tuple[str, list[FittedCell | None]]]
    reference: FittedCell | None  # the exact-solution fit
    anchor: float  # the truth, else the exact-solution fit's value (NaN without either)
    anchor_name: str


def fitted_tables(results) -> list[FittedTable]:
    """One table per fitted key; [] when the file holds no fits."""
    fits = results.fits
    if fits is None or fits.table.empty:
        return []
    rows = fit_rows(fits)
    frequency = spring_frequency(results, fits)
    dts = sorted({row.dt for row in rows})
    anchors, anchor_name = anchor_values(fits)
    reference = fits.reference
    tables = []
    for key in fits.parameters:
        cells = {(row.label, row.dt): FittedCell(row.values[key], row.stderr[key], row.predicted[key], row.status)
                 for row in rows}
        exact = (FittedCell(float(reference[key]), float(reference[f"{key} stderr"]), math.nan, reference["status"])
                 if reference is not None else None)
        tables.append(FittedTable(key, key_unit(key), dts, [dt * frequency if frequency else math.nan for dt in dts],
                                  [(label, [cells.get((label, dt)) for dt in dts]) for label in labels_of(rows)],
                                  exact, anchors.get(key, math.nan), anchor_name))
    return tables


@dataclass(frozen=True)
class TransferCell:
    relative_error: float
    status: str  # ok | diverged | failed: ...

    def text(self) -> str:
        return percent_text(self.relative_error) if self.status == "ok" else self.status

    @property
    def within(self) -> bool:
        return self.status == "ok" and self.relative_error <= TRANSFER_TOLERANCE


@dataclass(frozen=True)
class TransferRow:
    fit_id: str
    label: str
    dt: float  # NaN for the exact-solution fit
    cells: list[TransferCell | None]


@dataclass(frozen=True)
class TransferTable:
    """Rows the fits (the exact-solution fit first), columns the targets (integrator, dt) their values ran with."""

    targets: list[tuple[str, float]]
    rows: list[TransferRow]


def transfer_table(fits) -> TransferTable | None:
    """The transfer table as rows and columns; None when the file holds none."""
    transfer = fits.transfer if fits is not None else None
    if transfer is None or len(transfer) == 0:
        return None
    records = transfer.to_dict("records")
    targets = list(dict.fromkeys((record["integrator"], float(record["dt"])) for record in records))
    cells = {(record["fit_id"], record["integrator"], float(record["dt"])):
             TransferCell(float(record["relative_error"]), str(record["status"])) for record in records}
    rows = []
    for fit in fits.table.to_dict("records"):
        mine = [cells.get((fit["fit_id"], integrator, dt)) for integrator, dt in targets]
        if any(cell is not None for cell in mine):
            rows.append(TransferRow(fit["fit_id"], fit["label"], float(fit["dt"]), mine))
    return TransferTable(targets, rows)


def source_text(fits) -> str:
    """What was fitted to: the source, the observations (count, span, coordinates) and the weights."""
    t = fits.observed_t
    span = f"{t.size} times from {t[0]:g} to {t[-1]:g} s" if t.size else "no times"
    names = ", ".join(map(str, fits.names))
    return f"{fits.source}; {span}, coordinates {names}; weights: {fits.weights}"


__all__ = ["FittedCell", "FittedTable", "TransferCell", "TransferRow", "TransferTable", "anchor_values",
           "calibration_findings", "fit_rows", "fitted_tables", "key_label", "key_symbol", "key_unit",
           "same_trajectory_groups", "same_value_groups", "source_text", "spring_frequency", "transfer_table"]
