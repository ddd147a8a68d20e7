"""Exception types that carry a user-facing, one-line explanation.

Every error raised on bad input derives from :class:`ShsasError`; the CLI turns it into a
one-line message and exit code 2, the API into a 4xx response. Messages name the offending
field and, where there is one, the fix.
"""

from __future__ import annotations

from typing import Any


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


#: pydantic comparison error types -> (context key, operator) for the fix text.
_BOUNDS = {"greater_than": ("gt", ">"), "greater_than_equal": ("ge", "≥"), "less_than": ("lt", "<"),
           "less_than_equal": ("le", "≤")}


def pydantic_fix(err: Any, fields: list[str], doc: str) -> str:
    """How to fix one pydantic validation error (an item of ``ValidationError.errors()``).

    Args:
        fields: the model's field names, listed for an unknown key.
        doc: where the fields are documented, e.g. ``"docs/formats.md, meta table"``.
    """
    kind, ctx = err["type"], err.get("ctx") or {}
    if "fix" in ctx:  # a validator's own fix (see survey._rule)
        return str(ctx["fix"])
    if kind == "extra_forbidden":
        return f"remove it or correct the spelling; the fields are {', '.join(fields)} ({doc})"
    if kind in _BOUNDS:
        key, op = _BOUNDS[kind]
        return f"give a value {op} {ctx.get(key)} ({doc})"
    if kind == "literal_error":
        return f"use one of {ctx.get('expected')}"
    if kind.startswith(("float_", "int_", "bool_", "finite_")):
        return f"give a number, in the units of {doc}"
    if kind == "string_too_long":
        return f"shorten it to at most {ctx.get('max_length')} characters"
    if kind.startswith("string_"):
        return "give a string"
    if kind in ("tuple_type", "list_type", "too_short", "too_long"):
        return f"give a list of the length {doc} gives"
    if kind in ("model_type", "model_attributes_type", "dict_type"):
        return "give a JSON object"
    if kind.startswith("json_"):
        return "send valid JSON, e.g. from json.dumps"
    return f"see {doc}"


class UnsafeFileError(SurveyValidationError):
    """A file asks to read something outside itself or to execute code (external links,
    external storage, virtual datasets, pickles with callables)."""


class UnsupportedFormatError(ShsasError, ValueError):
    """The input is not in any format shsas can read."""


class Cancelled(Exception):
    """Raised inside long work when ``should_stop()`` returned True.

    Not a :class:`ShsasError`: a cancellation is not bad input.
    """
