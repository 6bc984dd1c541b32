"""tests/compare_results.py, the refactoring guard: two runs of one config are the same to it, and one ulp or one
attribute more is a difference it reports."""

from __future__ import annotations

import h5py
import numpy as np

import simrun
from compare_results import differences

TINY = ("name: tiny\nsystem: {type: spring_mass}\nintegrators: [backward_euler, symplectic_euler]\nduration: 0.2\n"
        "sweep: {dt: [0.01, 0.02]}\n")


def test_two_runs_are_the_same_and_one_ulp_is_a_difference(tmp_path):
    for name in ("a", "b"):
        simrun.run(TINY, output=tmp_path / name, jobs=1, progress=False, figures=False)
    old, new = tmp_path / "a" / "results.h5", tmp_path / "b" / "results.h5"
    assert differences(old, new) == []  # wall times and creation times differ: they are left out
    with h5py.File(new, "r+") as file:
        run = next(iter(file["runs"].values()))
        energy = run["energy"][()]
        energy[3] = np.nextafter(energy[3], np.inf)
        run["energy"][...] = energy
        run.attrs["not_there_before"] = 1
    found = differences(old, new)
    assert len(found) == 2, found
    assert any("energy: dataset differs" in line for line in found)
    assert any("'not_there_before' only in new" in line for line in found)


def test_paths_of_two_checkouts_are_one_through_aliases(tmp_path):
    for name, folder in (("a", "/old/checkout"), ("b", "/new/checkout")):
        with h5py.File(tmp_path / f"{name}.h5", "w") as file:
            file.attrs["resolved_config"] = f"model: {folder}/models/strip.obj\n"
    old, new = tmp_path / "a.h5", tmp_path / "b.h5"
    assert len(differences(old, new)) == 1
    assert differences(old, new, aliases=[("/old/checkout", "/new/checkout")]) == []


def test_summary_rows_are_compared_run_by_run_whatever_order_the_runs_finished_in(tmp_path):
    simrun.run(TINY, output=tmp_path / "a", jobs=1, progress=False, figures=False)
    old = tmp_path / "a" / "results.h5"
    new = tmp_path / "b.h5"
    new.write_bytes(old.read_bytes())
    with h5py.File(new, "r+") as file:
        rows = file["summary"][()]
        file["summary"][...] = rows[::-1]
        assert rows["run_id"][0] != rows["run_id"][-1]
    assert differences(old, new) == []
    with h5py.File(new, "r+") as file:
        rows = file["summary"][()]
        rows["steps"][0] += 1
        file["summary"][...] = rows
    assert any("summary: dataset differs" in line for line in differences(old, new))
