"""``alacs`` command-line tool for the ALACS sensor (see ``alacs --help``)."""

__version__ = "1.0.0"
