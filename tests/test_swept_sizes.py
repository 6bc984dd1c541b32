"""A sweep over the size of the system (system.resolution) with methods that take different swept keys: the report
draws the runs' snapshots at one scale though their frames differ in shape, and the findings word the settings of
methods that lack a key (XPBD takes no solver keys) without failing. Both are needed by the shipped
realtime_solvers.yaml, which sweeps three cloth sizes."""

from __future__ import annotations

import simrun
from simrun.findings.base import across_settings
from simrun.report.page import write_report


def test_a_report_over_swept_sizes_and_solvers_is_written(tmp_path):
    config = {"name": "sizes", "system": {"type": "cloth", "resolution": [3, 3], "stretch_stiffness": 100.0,
                                          "shear_stiffness": 10.0, "bend_stiffness": 1.0, "damping": 0.0},
              "integrators": ["backward_euler", {"type": "xpbd", "substeps": 4}], "duration": 0.1,
              "solver": {"tolerance": 1e-8, "max_iterations": 100, "on_not_converged": "accept"},
              "sweep": {"dt": [0.02], "solver.type": ["newton", "vbd"], "system.resolution": [[3, 3], [5, 4]]},
              "record": {"frames_every": 1}}
    results = simrun.run(config, output=tmp_path / "sizes", jobs=1, progress=False, figures=False)
    page = tmp_path / "report.html"
    write_report(results.path, page, reference="none")
    text = page.read_text()
    assert "system.resolution" in text and "snapshots" in text.lower()


def test_settings_that_lack_a_key_are_worded_by_the_keys_they_have():
    settings = {"newton at 8": {"solver.type": "newton", "system.resolution": [8, 8]},
                "xpbd at 8": {"system.resolution": [8, 8]}, "xpbd at 12": {"system.resolution": [12, 12]},
                "newton at 12": {"solver.type": "newton", "system.resolution": [12, 12]}}
    text = across_settings([("xpbd[substeps=5]", "xpbd at 8"), ("xpbd[substeps=5]", "xpbd at 12"),
                            ("backward_euler", "newton at 8")], settings)
    xpbd, backward_euler = text.split("; ")
    assert xpbd.startswith("xpbd[substeps=5] at 2 of 4 settings (system.resolution ")  # its one key, its two values
    assert "[8, 8]" in xpbd and "[12, 12]" in xpbd and "solver.type" not in xpbd
    assert backward_euler == "backward_euler at newton at 8"
