"""The experiment: the YAML config as validated models (``config``), the ``fit`` block of a calibration (``fit``),
and the sweep expanded into runs (``sweep``). Nothing here steps, writes or reads results."""
