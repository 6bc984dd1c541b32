"""Where things are in a results file, and which versions of it this simrun reads (docs/results-format.md)."""

FORMAT_VERSION = 3  # what this simrun writes
READABLE_VERSIONS = (1, 2, 3)
RESULTS_NAME = "results.h5"
# runs stepped together as lanes (runner/execution/lanes.py) are stored by chunk: /lanes/<chunk> (format 3), read
# by simrun.results.lanes into the same StoredRun as the runs of /runs
LANES_GROUP = "lanes"
LANE_TABLE = "runs"  # a chunk's table: a row per run, a field per attribute
# attributes a run has only sometimes, stored in a chunk's columns as NaN where the run has none; `error` is there
# exactly when `error_time` is (and may itself be NaN: no exact solution, or one that overflowed); the error norms
# over the run are stored only where they are not NaN (runner/execution/measures.py, error_norms)
ERROR_NORMS = ("final_velocity_error", "max_error", "max_velocity_error")
OPTIONAL_LANE_COLUMNS = ("t_diverged", "error_time", *ERROR_NORMS)

# model_constraints: what each vertex of a run with frames is held to (runner/execution/simulate.py); 0: free
VERTEX_KINDS = {"pinned": 1, "prescribed": 2, "sliding": 3}
