"""simrun.calibration (folder runner/calibration/): `simrun fit`, parameters fitted to observed motion per integrator
and time step (docs/calibration.md). params: the config block; keys: fitted config keys; observations: what is
fitted to; engine: one least-squares fit; predicted: what theory says the spring fit finds; store and results: the
`fits` group of the results file; pipeline: `simrun.fit`."""
