"""simrun (folder runner/): a batch experiment runner for the time integrators of physics-based animation.

    import simrun
    results = simrun.run("configs/quickstart.yaml", output="/tmp/quickstart")   # the pipeline: simrun.pipeline
    results = simrun.load("results/quickstart/results.h5")                      # the reader: simrun.results
    results = simrun.fit("configs/calibrate_spring.yaml")                       # a calibration: simrun.calibration

The design card's folders are installed as one package: runner/ is `simrun` (the application),
systems/ is `simrun.systems`, integrators/ is `simrun.integrators`, solvers/ is `simrun.solvers`.
`run`, `fit` and `load` are imported on first use, so that `import simrun` stays light for the command line.
"""

from simrun.version import __version__

__all__ = ["__version__", "fit", "load", "run"]


def __getattr__(name: str):
    if name == "run":
        from simrun.pipeline import run

        return run
    if name == "fit":
        from simrun.calibration.pipeline import fit

        return fit
    if name == "load":
        from simrun.results import load

        return load
    raise AttributeError(f"module 'simrun' has no attribute {name!r}")
