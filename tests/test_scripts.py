"""simrun's Python API from a plain script: `simrun.run` and `simrun.fit` at a script's top level, without
`if __name__ == "__main__":`, on the process pool. multiprocessing's workers would import the script again and start
a pool inside each worker; simrun's start without it. Each script runs as a subprocess of its own, from a folder of
its own, as a user runs it: `python my_script.py`."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import h5py

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _run_script(folder: Path, body: str) -> subprocess.CompletedProcess:
    script = folder / "my_script.py"
    script.write_text(textwrap.dedent(body))
    return subprocess.run([sys.executable, str(script)], cwd=folder, capture_output=True, text=True, timeout=600)


def test_simrun_run_at_a_scripts_top_level_runs_on_the_pool(tmp_path):
    """quickstart.yaml on two workers from an unguarded script: every run in, nothing printed on stderr, and the
    script's own top level ran once (its print is seen once)."""
    done = _run_script(tmp_path, f"""
        import simrun

        print("top level")
        results = simrun.run({str(CONFIGS / 'quickstart.yaml')!r}, output="out", jobs=2, progress=False, figures=False)
        print(sorted(results.ran.items()))
        """)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "", done.stderr
    assert done.stdout.splitlines() == ["top level", "[('diverged', 4), ('ok', 14)]"]
    with h5py.File(tmp_path / "out" / "results.h5", "r") as file:
        assert len(file["runs"]) == 18 and all(group.attrs["complete"] for group in file["runs"].values())


def test_simrun_fit_at_a_scripts_top_level_runs_on_the_pool(tmp_path):
    done = _run_script(tmp_path, f"""
        import simrun

        results = simrun.fit({str(CONFIGS / 'calibrate_spring.yaml')!r}, output="fit", jobs=2, progress=False,
                             figures=False, overrides=["integrators=[backward_euler,rk4]", "sweep.dt=[0.05,0.1]"])
        print(sorted(results.fits.table["status"]))
        """)
    assert done.returncode == 0, done.stderr
    assert done.stderr == "", done.stderr
    assert done.stdout.strip() == str(["converged"] * 5)


def test_a_plugin_defined_in_a_guarded_script_runs_on_the_pool(tmp_path):
    """A plug-in system defined in the script itself (type "__main__:..."), which runs simrun under
    `if __name__ == "__main__":`: its runs need the script's classes, so those workers import it, as multiprocessing
    does; both runs are in."""
    plugins = Path(__file__).resolve().parent / "plugins"
    done = _run_script(tmp_path, f"""
        import sys
        from typing import Literal

        sys.path.insert(0, {str(plugins)!r})
        import simrun
        from pendulum_chain import Chain, ChainParams


        class ScriptChainParams(ChainParams):
            type: Literal["__main__:ScriptChainParams"] = "__main__:ScriptChainParams"


        ScriptChainParams.system_class = Chain

        if __name__ == "__main__":
            config = {{"name": "script", "system": {{"type": "__main__:ScriptChainParams", "count": 1}},
                      "integrators": ["symplectic_euler", "implicit_midpoint"], "duration": 0.05, "sweep": {{"dt": [1e-4]}}}}
            print(simrun.run(config, output="out", jobs=2, progress=False, figures=False).ran)
        """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "{'ok': 2}"
