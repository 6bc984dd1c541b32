"""What a model of vertices that cannot be simulated raises, and what loading one mended: shared by every system of
vertices (mass_spring, fem, the cloth) and by contact, whose checks against the model raise the same error."""

from __future__ import annotations


class ModelError(ValueError):
    """A model that cannot be simulated: the message names the problem (the config path is added by the caller)."""


class ModelWarning(UserWarning):
    """What loading a model mended and the user should know (degenerate faces of a scanned mesh): the command line
    prints it as one line (``one_line``); the sweep's workers, which build the model again, do not repeat it."""

    one_line = True
