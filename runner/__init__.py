"""simrun: a batch experiment runner for the time integrators of physics-based animation."""

__version__ = "0.1.0"
