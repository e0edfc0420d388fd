"""Errors the pipeline raises on purpose: each carries a one-line message fit for the user."""


class FFVizError(Exception):
    """Base of every expected failure; the CLI prints str(error) on one line and exits non-zero."""

    exit_code = 1


class InputError(FFVizError):
    """The input cannot be used: missing, not a video, no video stream, too few frames, corrupt."""

    exit_code = 2


class OutputError(FFVizError):
    """The output cannot be written: same path as the input, unwritable, disk full."""

    exit_code = 3


class ConfigError(FFVizError):
    """An option value that makes no sense (negative radius, unknown model, ...)."""

    exit_code = 2
