"""The error a user's input gets: light, so that the command line can name it before any heavy import."""

from __future__ import annotations


class ConfigError(Exception):
    """A config that cannot be run; the message is one line naming the field and what is allowed."""
