"""Fixtures shared by the CLI tests: a unique virtual channel and a fake sensor on it."""

from test_cli import channel, sensor  # noqa: F401  (pytest fixtures)
