"""The one error type for a mistake in what a user asked for or handed in: a flag's value, a
missing or foreign file, a run that cannot go on. ``python -m train`` prints it as one line and
exits 2 (train/cli.py); anything else is a bug and keeps its traceback."""

from __future__ import annotations


class UsageError(ValueError):
    """A flag or file the user gave is unusable; the message names it and says why.

    A ValueError, so library callers that caught the ValueErrors raised before keep working."""


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line. A DataLoader worker's error comes back with the
    worker's whole traceback in its message; the original message is its last line."""
    text = str(exc).strip()
    if "Original Traceback" in text:
        last = text.splitlines()[-1]
        text = last.split(": ", 1)[1] if ": " in last else last  # drop "module.ErrorType: "
    return " ".join(text.split())
