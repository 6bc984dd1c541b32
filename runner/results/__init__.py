"""The results file on disk: its writer (``writer``: runs committed as they finish, resume, size admission), its
readers (``reader``: ``simrun.load``; ``lanes``: lane chunks; ``fits``: a calibration's fits; ``compat``: older
formats), and the output folder's lock (``lock``). What the rows hold is defined in ``simrun.format``.

``simrun.results.load(path)`` gives the ``Results`` of any results file (docs/results-format.md)."""

from simrun.results.reader import Results, StoredRun, load, load_summary

__all__ = ["Results", "StoredRun", "load", "load_summary"]
