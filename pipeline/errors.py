"""The error a user can fix (one line, exit status 2) and messages made safe to print."""


def escape(text: object) -> str:
    """``text`` with every non-printable character as a Python escape (``\\n``, ``\\x1b``).

    Printable text (letters of any script, spaces) is unchanged; a backslash is
    kept as it is.  Used for every message the CLI prints, so that a file named
    ``"a\\nb"`` or holding ``"\\x1b[2J"`` cannot split the error line or drive the
    terminal.
    """
    text = str(text)
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


class InputError(ValueError):
    """Bad input: a message naming the file (and field) and the problem."""


class StageSkipped(Exception):  # noqa: N818 - a signal, not an error
    """Raised by a ``photosurf run`` stage that cannot apply to this data; the run goes on.

    The message says why (a named warning in the manifest, the summary and the
    report); stages that need this one are blocked, stages that only read it
    when present go on.
    """
