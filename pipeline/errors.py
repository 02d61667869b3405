"""The error a user can fix: printed by the CLI as one line, exit status 2."""


class InputError(ValueError):
    """Bad input: a message naming the file (and field) and the problem."""


class StageSkipped(Exception):  # noqa: N818 - a signal, not an error
    """Raised by a ``photosurf run`` stage that cannot apply to this data; the run goes on.

    The message says why (a named warning in the manifest, the summary and the
    report); stages that need this one are blocked, stages that only read it
    when present go on.
    """
