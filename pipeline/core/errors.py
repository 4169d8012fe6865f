"""Errors raised on bad configuration or bad input.

Both derive from ``ValueError`` so callers that already catch ``ValueError`` keep
working; the message always names the field (or file/column/row) and the value.
"""


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range."""


class InputError(ValueError):
    """Data handed to the pipeline (joints, poses, drill plans) is malformed."""
