"""User-facing errors.

Anything the user can fix (a missing file, a video that does not decode, an absurd parameter)
raises :class:`EgovidError`. The CLI prints it as one line, ``error: <problem>; <fix>``, and exits
with status 2; it never shows a traceback for these.
"""

from __future__ import annotations


class EgovidError(Exception):
    """A problem with the user's input, with the fix to suggest.

    Parameters
    ----------
    problem:
        What is wrong, naming the offending file or value.
    fix:
        What the user should do about it (optional).
    """

    def __init__(self, problem: str, fix: str | None = None) -> None:
        self.problem = problem
        self.fix = fix
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """The message as a single line: ``problem; fix``."""
        text = " ".join(self.problem.split())
        if self.fix:
            text += "; " + " ".join(self.fix.split())
        return text


def require(condition: bool, problem: str, fix: str | None = None) -> None:
    """Raise :class:`EgovidError` unless ``condition`` holds."""
    if not condition:
        raise EgovidError(problem, fix)
