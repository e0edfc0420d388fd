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


class ConfigError(FFVizError, ValueError):
    """An option value that makes no sense (negative radius, unknown model, ...).

    Every config dataclass raises it from ``__post_init__``, so a bad value fails where the config is built.
    Also a ValueError: code that caught the ValueError configs raised before keeps working.
    """

    exit_code = 2
