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
