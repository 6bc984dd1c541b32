"""Where runs are simulated: one run's stepping loop (``simulate``, no I/O), runs stepped together as lanes
(``lanes``, ``lane_recording``), and where they run (``executors``: serial, the process pool, Dask; ``workers``: the
pool's processes). What a run produced is a ``simrun.format.run_result.RunResult``."""
