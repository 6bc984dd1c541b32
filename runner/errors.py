"""The errors a user's input gets, in one module: light, so that the command line can name them before any
heavy import. Each message is one line naming the field (or file) and what is allowed; the command line
prints it after ``simrun: error:`` and exits with status 2."""

from __future__ import annotations


class ConfigError(Exception):
    """A config, option or input file that cannot be used; the message is one line naming the field and what is allowed."""


class OutputLocked(ConfigError):
    """Another simrun holds the output folder."""


class ResultsFileError(ConfigError):
    """A results file that cannot be read or resumed: missing, not HDF5, not simrun's, or of an unknown format version."""


class WorkerLost(ConfigError):
    """A worker process of the local pool ended abruptly (killed: out of memory, a signal): the runs that finished are
    in the results file, and the same command resumes."""

    def __init__(self, doing: str):
        super().__init__(f"a worker process ended abruptly while {doing} (killed by the system: out of memory? a "
                         "signal?); what finished is in the results file: run the same command again to resume the "
                         "rest, with fewer --jobs if memory ran out")
