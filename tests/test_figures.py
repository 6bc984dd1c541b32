"""The figures (simrun.figures), drawn from results files that the real pipeline wrote (`simrun CONFIG --no-plots` into tmp_path).

On the spring with k = 100 N/m, m = 1 kg (w = 10 rad/s) and dt = 0.25 s (h w = 2.5) forward Euler
multiplies the energy by 1 + (h w)^2 = 7.25 per step and symplectic Euler is past its limit h w < 2,
so both diverge (|E - E0| > 1e6 |E0|) within 2 s: the figures must cope with runs that stopped early.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pytest
import yaml
from matplotlib.image import imread

from simrun.cli import main
from simrun.figures import CALIBRATION, FIGURES, draw_figures, figure_data
from simrun.figures.solver_work import newton_iterations_vs_dt
from simrun.results import load

# runs on the undamped test equation (spring, linear circular motion) add the predicted-vs-measured curves
TEST_EQUATION = {"artificial_damping", "spectral_radius_and_period"}
# the figures every file with runs of the small systems gets (from the registry: a new figure joins these sets)
# the calibration's figures need a file of `simrun fit` (tests/test_calibration_figures.py)
CALIBRATION_FIGURES = {name for name, entry in FIGURES.items() if entry.needs == CALIBRATION}
MAPS = {"damping_map"}  # a sweep over h w and the damping ratio: tests/test_lanes.py draws it
SOLVER_SWEEPS = {"cost_vs_accuracy"}  # drawn where solver.type is swept
CONTACT = {"contact_distance"}  # runs with contact: tests/test_contact_configs.py
FEM = {"volume_ratio"}  # finite-element runs: tests/test_fem_runs.py
ALWAYS = (set(FIGURES) - TEST_EQUATION - CALIBRATION_FIGURES - MAPS - SOLVER_SWEEPS - CONTACT - FEM
          - {"orbits", "snapshots"})
EULERS = ["forward_euler", "symplectic_euler", "backward_euler"]
SPRING = {"system": {"type": "spring_mass", "stiffness": 100.0}, "integrators": EULERS,
          "duration": 2.0, "sweep": {"dt": [0.01, 0.05, 0.25]}}
ORBIT = {"system": {"type": "circular_motion", "force": "gravity"}, "integrators": EULERS,
         "duration": 6.3, "sweep": {"dt": [0.05, 0.2]}}  # about one revolution (w = 1 rad/s)
EXPLICIT = {"system": {"type": "spring_mass"}, "integrators": ["forward_euler", "symplectic_euler"],
            "duration": 1.0, "sweep": {"dt": [0.01, 0.1]}}
GROUPS = {"system": {"type": "spring_mass"}, "integrators": ["symplectic_euler", "backward_euler"],
          "duration": 1.0, "sweep": {"dt": [0.01, 0.1], "system.stiffness": [10.0, 100.0]}}


def run_pipeline(folder: Path, name: str, experiment: dict) -> Path:
    """Write the config into folder, run `simrun CONFIG --no-plots` on it, return the results file."""
    folder.mkdir(parents=True, exist_ok=True)
    output = folder / name
    config = folder / f"{name}.yaml"
    config.write_text(yaml.safe_dump({"name": name, **experiment, "output": str(output)}))
    assert main([str(config), "-q", "--no-plots"]) == 0
    return output / "results.h5"


@pytest.fixture(scope="module")
def spring(tmp_path_factory) -> Path:
    return run_pipeline(tmp_path_factory.mktemp("spring"), "spring", SPRING)


@pytest.fixture(scope="module")
def orbit(tmp_path_factory) -> Path:
    return run_pipeline(tmp_path_factory.mktemp("orbit"), "orbit", ORBIT)


def statuses(path: Path) -> dict[str, str]:
    with h5py.File(path, "r") as file:
        return {run_id: str(group.attrs["status"]) for run_id, group in file["runs"].items()}


def assert_figures(paths: list[Path], folder: Path, names: set[str], svg: bool = False) -> None:
    """Exactly `names` were drawn, each as a non-empty PNG (that opens), and as SVG with ``svg``, all inside folder."""
    extensions = ("png", "svg") if svg else ("png",)
    assert sorted(paths) == sorted(folder / f"{name}.{ext}" for name in names for ext in extensions)
    for path in paths:
        assert path.is_file() and path.stat().st_size > 1000, path
    for name in names:
        image = imread(folder / f"{name}.png")
        assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100
        assert np.ptp(image[..., :3]) > 0, f"{name}.png is blank"
        if svg:
            assert (folder / f"{name}.svg").read_text().lstrip().startswith("<?xml")


def test_spring_figures_with_diverged_runs(spring, tmp_path):
    assert {"diverged"} <= set(statuses(spring).values())  # the case this test is about
    style = dict(matplotlib.rcParams)
    paths = draw_figures(spring, tmp_path / "figures", svg=True)
    assert_figures(paths, tmp_path / "figures", ALWAYS | TEST_EQUATION, svg=True)  # no orbits for the spring
    assert plt.get_fignums() == []  # every figure closed
    assert dict(matplotlib.rcParams) == style  # no global style side effects


def test_circular_motion_adds_the_orbits(orbit, tmp_path):
    paths = draw_figures(orbit, tmp_path)
    assert_figures(paths, tmp_path, ALWAYS | {"orbits"})


def test_explicit_methods_only_skip_newton_iterations(tmp_path):
    """Explicit methods never call the solver: no Newton figure (the full drawing is checked in the redraw test)."""
    results = run_pipeline(tmp_path, "explicit", EXPLICIT)
    assert newton_iterations_vs_dt(figure_data(load(results))) is None


def test_every_figure_copes_with_failed_runs_with_few_or_no_samples(orbit, tmp_path):
    """One run failed after one sample, one before any step (empty series), one diverged at once."""
    path = tmp_path / "results.h5"
    shutil.copy(orbit, path)
    with h5py.File(path, "r+") as file:
        runs = list(file["runs"].values())
        truncate(runs[0], samples=1, status="failed")
        truncate(runs[-1], samples=0, status="failed")
        truncate(runs[3], samples=2, status="diverged")
        runs[3].attrs["t_diverged"] = float(runs[3]["t"][-1])
    paths = draw_figures(path, tmp_path / "figures")
    assert_figures(paths, tmp_path / "figures", ALWAYS | {"orbits"})


def truncate(group: h5py.Group, samples: int, status: str) -> None:
    """Cut a run's series to its first `samples` rows (and as many steps), as a run that stopped early."""
    for key in list(group):
        data = group[key][()]
        del group[key]
        group.create_dataset(key, data=data[:samples])
    group.attrs["status"] = status
    group.attrs["steps"] = max(samples - 1, 0)


def test_one_panel_row_per_group_of_swept_parameters(tmp_path):
    results = run_pipeline(tmp_path, "groups", GROUPS)
    loaded = figure_data(load(results))
    assert [title for title, _ in loaded.groups] == ["system.stiffness = 10", "system.stiffness = 100"]
    assert all(len(runs) == 4 for _, runs in loaded.groups)  # 2 integrators x 2 dt each
    paths = draw_figures(results, tmp_path / "figures")
    assert_figures(paths, tmp_path / "figures", ALWAYS | TEST_EQUATION)


def test_colours_follow_the_sorted_labels(spring):
    """One colour per label for every figure: sorted labels -> tab10, so adding a method does not recolour others."""
    loaded = figure_data(load(spring))
    assert loaded.labels == EULERS  # config order for legends and rows
    palette = plt.get_cmap("tab10")
    assert loaded.colours == {label: palette(number) for number, label in enumerate(sorted(EULERS))}


def test_figures_are_redrawn_from_the_results_file_alone(tmp_path):
    """A copy of results.h5 is enough: the output folder (config, everything else) is gone before drawing."""
    results = run_pipeline(tmp_path / "first", "explicit", EXPLICIT)
    copy = tmp_path / "elsewhere" / "results.h5"
    copy.parent.mkdir()
    shutil.copy(results, copy)
    shutil.rmtree(tmp_path / "first")
    paths = draw_figures(copy, tmp_path / "elsewhere" / "figures")
    # explicit methods only: every figure but the Newton iterations
    assert_figures(paths, tmp_path / "elsewhere" / "figures", (ALWAYS | TEST_EQUATION) - {"newton_iterations_vs_dt"})


def imported_by(module: str) -> set[str]:
    """The simrun modules a fresh interpreter has loaded after importing `module`."""
    code = (f"import json, sys, {module}; "
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('simrun'))))")
    return set(json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout))


def test_the_reader_and_the_figures_import_no_config_simulation_or_library():
    """Data flows one way: the results reader depends on the file format only, the figures on it and on the derived
    per-run data. Importing them loads no config, simulation, writer, CLI or library package (the theory figures load
    simrun.analysis.oscillator, and with it the integrators, only when they draw; the reference's and equal-error
    modules of analysis, which the work-precision figure reads, import only numpy and the format)."""
    face = {"simrun", "simrun.errors", "simrun.version"}
    reader = imported_by("simrun.results")
    assert reader - face == {"simrun.format", "simrun.format.layout", "simrun.format.record", "simrun.format.summary",
                             "simrun.results", "simrun.results.fits", "simrun.results.lanes", "simrun.results.parameters",
                             "simrun.results.reader"}
    figures = imported_by("simrun.figures")
    outside = {module for module in figures - face - reader if not module.startswith("simrun.figures")}
    assert outside == {"simrun.analysis", "simrun.analysis.runs", "simrun.analysis.damping_map",
                       "simrun.analysis.reference", "simrun.analysis.equal_error"}


def test_a_file_without_runs_gives_no_figures(tmp_path):
    path = tmp_path / "results.h5"
    with h5py.File(path, "w") as file:
        file.attrs["format_version"] = 2
        file.create_group("runs")
    assert draw_figures(path, tmp_path / "figures") == []
    assert (tmp_path / "figures").is_dir()


def test_figures_drawn_by_workers_are_the_files_drawn_in_one_process(spring, tmp_path):
    """draw_figures with jobs=2 shares the figures out among two worker processes: the same files, byte for byte
    (PNG and SVG, whose element ids are salted with a fixed string), in the same order."""
    serial = draw_figures(spring, tmp_path / "one", jobs=1, svg=True)
    shared = draw_figures(spring, tmp_path / "two", jobs=2, svg=True)
    assert [path.name for path in shared] == [path.name for path in serial] and len(serial) >= 10
    for one, two in zip(serial, shared):
        assert one.read_bytes() == two.read_bytes(), one.name
