"""Exception types that carry a user-facing, one-line explanation.

Every error raised on bad input derives from :class:`ShsasError`; the CLI turns it into a
one-line message and exit code 2, the API into a 4xx response. Messages name the offending
field and, where there is one, the fix.
"""

from __future__ import annotations


class ShsasError(Exception):
    """Base class for errors caused by user input (files, specs, options)."""

    exit_code = 2


class SurveyValidationError(ShsasError, ValueError):
    """A survey (in memory or on disk) violates the schema.

    Args:
        field: dotted path of the offending field, e.g. ``"meta.fs"`` or ``"pings/tx"``.
        problem: what is wrong, with the offending value.
        fix: how to fix it; without one the message points to the layouts in docs/formats.md,
            so that every message has the ``(fix: ...)`` docs/usage.md promises.
    """

    #: The fix of an error raised without one.
    DEFAULT_FIX = "see the layout this field must follow in docs/formats.md"

    def __init__(self, field: str, problem: str, fix: str | None = None):
        self.field = field
        self.problem = problem
        self.fix = fix or self.DEFAULT_FIX
        super().__init__(f"{field}: {problem} (fix: {self.fix})")


class UnsafeFileError(SurveyValidationError):
    """A file asks to read something outside itself or to execute code (external links,
    external storage, virtual datasets, pickles with callables)."""


class UnsupportedFormatError(ShsasError, ValueError):
    """The input is not in any format shsas can read."""


class Cancelled(Exception):
    """Raised inside long work when ``should_stop()`` returned True.

    Not a :class:`ShsasError`: a cancellation is not bad input.
    """
