"""The error a user can fix: printed by the CLI as one line, exit status 2."""


class InputError(ValueError):
    """Bad input: a message naming the file (and field) and the problem."""
