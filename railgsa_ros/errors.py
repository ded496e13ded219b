"""Errors that the command line turns into a one-line message and exit code 2."""


class RailGsaError(Exception):
    """Base class: a user-facing error with a one-line message (CLI exit code 2)."""


class ConfigError(RailGsaError):
    """An invalid configuration value or file; the message names the field or file."""


class InputError(RailGsaError):
    """Unusable input data: an unreadable, empty, truncated or corrupt file or stream."""


class InputWarning(UserWarning):
    """Input data used with a loss that is counted and reported (malformed messages skipped);
    the CLI prints it as one line ``warning: <message>``."""
