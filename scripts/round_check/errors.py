"""Bad input (a file, a setting, an argument): exit code 2, distinct from violations found (1)."""


class InputError(Exception):
    """An input the checker cannot judge; the message names the file, the boom and the row."""
