"""simrun's version: stored in every results file's provenance, printed by ``simrun --version``."""

__version__ = "0.1.0"
