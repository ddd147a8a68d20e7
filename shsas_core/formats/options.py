"""Typed import options: each format declares a pydantic model of the options its reader takes.

Options arrive as keywords (``load_survey(path, background=...)``), as a mapping, or as the
format's model itself; :func:`parse_options` validates them against the model of the format
the file turned out to be, so an option that format does not take, or a value out of range, is
a one-line error naming the option rather than a ``TypeError`` deep in a reader.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pydantic
from pydantic import BaseModel, ConfigDict, Field

from shsas_core.common.errors import SurveyValidationError, pydantic_fix
from shsas_core.data.survey import SceneBox

DOC = "docs/formats.md"


class FormatOptions(BaseModel):
    """Options of a format that takes none (the canonical file); the base of every options model."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    def values(self) -> dict[str, Any]:
        """The options as keywords for the reader, values as validated (models stay models)."""
        return {name: getattr(self, name) for name in type(self).model_fields}


class ImportOptions(FormatOptions):
    """Options every importer of a foreign format takes."""

    scene_box: SceneBox | None = Field(None, description="the scene box, m; None: the format's default")


def parse_options(fmt_name: str, model: type[FormatOptions], options: FormatOptions | Mapping[str, Any] | None,
                  keywords: Mapping[str, Any]) -> FormatOptions:
    """``options`` (a model or a mapping) with ``keywords`` on top, validated as ``model``.

    Raises:
        SurveyValidationError: named by the first offending option, with a fix.
    """
    if isinstance(options, FormatOptions):
        if not isinstance(options, model):
            raise SurveyValidationError(
                "options", f"are {type(options).__name__}, but the file is a {fmt_name} survey, which takes "
                f"{model.__name__}", f"give {model.__name__} or keywords; the format is detected from the file")
        if not keywords:
            return options
        options = options.values()
    given = {**(options or {}), **keywords}
    try:
        return model.model_validate(given)
    except pydantic.ValidationError as exc:
        raise _named(fmt_name, model, exc) from None


def _named(fmt_name: str, model: type[FormatOptions], exc: pydantic.ValidationError) -> SurveyValidationError:
    err = exc.errors()[0]
    # the option itself: later parts of ``loc`` name union branches (``int``, ``SceneBox``), not options
    name = str(err["loc"][0]) if err["loc"] else "options"
    fields = list(model.model_fields)
    where = f"{DOC}, the {fmt_name} options"
    if err["type"] == "extra_forbidden":
        taken = f"{fmt_name} surveys take {', '.join(fields)}" if fields else f"{fmt_name} surveys take no options"
        return SurveyValidationError(name, f"is not an option of {fmt_name} surveys (got {err.get('input')!r})"[:300],
                                     f"remove it or correct the spelling; {taken} ({DOC})")
    return SurveyValidationError(name, f"{err['msg']} (got {err.get('input')!r})"[:300],
                                 pydantic_fix(err, fields, where))
