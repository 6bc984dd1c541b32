"""`simrun show`: the summary in 100 columns by default (--wide: every column), iteration columns named by the
solver, and CSV with units in its headers, on standard output or written whole into a file."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import pytest
import yaml

from simrun.analysis.rows import iteration_name
from simrun.cli import main
from simrun.report.summary_table import TERMINAL_WIDTH
from simrun.results import load

CONFIGS = Path(__file__).resolve().parent.parent / "configs"
# An explicit and an implicit method on the spring, the implicit one with each of two solvers.
MIXED = {"name": "mixed", "system": {"type": "spring_mass", "stiffness": 100.0}, "duration": 0.5,
         "integrators": ["symplectic_euler", "backward_euler"], "sweep": {"dt": [0.01, 0.05], "solver.type": ["newton", "lbfgs"]}}


@pytest.fixture(scope="module")
def quickstart(tmp_path_factory) -> Path:
    output = tmp_path_factory.mktemp("show") / "quickstart"
    assert main([str(CONFIGS / "quickstart.yaml"), "-q", "--no-plots", "--set", "duration=1.0",
                 "--output", str(output), "-j", "1"]) == 0
    return output / "results.h5"


def test_the_table_fits_100_columns_and_wide_shows_every_column(quickstart, capsys):
    assert main(["show", str(quickstart)]) == 0
    table = capsys.readouterr().out
    assert max(map(len, table.splitlines())) <= TERMINAL_WIDTH
    assert "quickstart: 18 runs" in table and "backward_euler" in table and "Newton" in table
    assert "--wide" in table  # says what it left out
    assert main(["show", str(quickstart), "--wide"]) == 0
    wide = capsys.readouterr().out
    assert "steps" in wide and "h w" in wide and "--wide" not in wide
    assert "E_ref = E0 (initial energy) = 50 J" in table.replace("\n  ", " ")


def test_csv_on_standard_output_with_the_results_file_after_the_option(quickstart, capsys):
    """`simrun show --csv results.h5`: --csv is a flag and leaves the results file alone."""
    assert main(["show", "--csv", str(quickstart)]) == 0
    rows = list(csv.DictReader(io.StringIO(capsys.readouterr().out)))
    assert len(rows) == 18
    units = {"dt_s", "wall_time_s", "error_m", "final_error_m", "error_time_s", "energy_reference_J",
             "max_rel_energy_drift", "measured_damping_over_w", "predicted_damping_over_w"}
    assert units <= set(rows[0])
    assert not {"dt", "wall_time", "final_error", "measured_damping"} & set(rows[0])  # no header without its unit
    assert {row["energy_reference_J"] for row in rows} == {"50.0"}


def test_csv_into_a_file_and_refused_where_it_cannot_be_written(quickstart, tmp_path, capsys):
    target = tmp_path / "new" / "summary.csv"
    assert main(["show", str(quickstart), "--output", str(target)]) == 0
    assert len(list(csv.DictReader(target.open()))) == 18
    capsys.readouterr()
    (tmp_path / "a_file").write_text("")
    assert main(["show", str(quickstart), "--csv", "--output", str(tmp_path / "a_file" / "summary.csv")]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("simrun: error: --output") and "\n" not in error
    assert not (tmp_path / "a_file" / "summary.csv").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_csv_refused_in_a_read_only_folder(quickstart, tmp_path, capsys):
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        assert main(["show", str(quickstart), "--output", str(folder / "summary.csv")]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
        assert list(folder.iterdir()) == []
    finally:
        folder.chmod(0o700)


def test_iteration_columns_are_named_by_the_solver(tmp_path, capsys):
    config = tmp_path / "mixed.yaml"
    config.write_text(yaml.safe_dump(MIXED))
    assert main([str(config), "-q", "--no-plots", "--output", str(tmp_path / "mixed"), "-j", "1"]) == 0
    results = tmp_path / "mixed" / "results.h5"
    assert main(["show", str(results), "--wide"]) == 0
    table = capsys.readouterr().out
    assert "solver" in table.splitlines()[1] + table.splitlines()[2] and "lbfgs" in table
    assert "Newton it/step" not in table  # the neutral name when solvers mix
    from simrun.analysis.rows import summary_rows
    from simrun.figures import figure_data

    loaded = load(results)
    with loaded.opened():
        rows = summary_rows(figure_data(loaded))
    assert iteration_name(rows) == "solver"
    assert iteration_name([row for row in rows if row.solver in ("", "lbfgs")]) == "L-BFGS"
    assert iteration_name([row for row in rows if row.solver in ("", "newton")]) == "Newton"
    assert {row.solver for row in rows if row.integrator == "symplectic_euler"} == {""}  # explicit: no solver
