"""The registry of survey formats: one :class:`Format` per format shsas reads.

A format is its name, a ``sniff`` that says from a :class:`~.probe.Probe` whether a path is one
of its files, a ``read`` that makes the :class:`~shsas_core.data.survey.Survey`, the pydantic
model of its options, and the name the service stores a job's input of that format under.
Detection asks every registered format and takes the strongest claim, so adding a format is
registering it: no other table names the formats.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import IntEnum
from pathlib import Path
from typing import Any

from shsas_core.common.errors import ShsasError, SurveyValidationError, UnsupportedFormatError
from shsas_core.common.progress import ProgressFn, no_progress
from shsas_core.data.survey import Survey
from shsas_core.formats.options import FormatOptions, parse_options
from shsas_core.formats.probe import Probe


class Claim(IntEnum):
    """How sure a format's ``sniff`` is that a path is one of its files."""

    NO = 0
    #: Not recognised, but of this format's kind (an HDF5 file, a zip), so that, when no format
    #: recognises it, this format's reader is the one that names what is wrong.
    FALLBACK = 1
    YES = 2


#: ``read(path, options, load_samples, progress) -> Survey``
Reader = Callable[[Path, Any, bool, ProgressFn], Survey]


@dataclass(frozen=True)
class Format:
    """One survey format.

    Attributes:
        name: the ``--format`` value and what detection returns, e.g. ``airsas-csv``.
        summary: what its files are, for messages, e.g. ``an AirSAS CSV scan folder or .zip``.
        sniff: ``sniff(probe) -> Claim``; looks only at what the probe offers (cheap).
        read: ``read(path, options, load_samples, progress) -> Survey``; ``options`` is an
            instance of ``options``; formats read in one go ignore ``progress``.
        options: the pydantic model of its options (every field has a default).
        stored_name: the file name the service stores a job's input of this format under (a
            format the service converts on upload names the canonical file).
    """

    name: str
    summary: str
    sniff: Callable[[Probe], Claim]
    read: Reader
    options: type[FormatOptions]
    stored_name: str


_REGISTRY: dict[str, Format] = {}


def register(fmt: Format) -> Format:
    """Add ``fmt``; on equal claims, formats registered earlier win."""
    if fmt.name in _REGISTRY or fmt.name == "auto":
        raise ValueError(f"a format named {fmt.name!r} is already registered")
    _REGISTRY[fmt.name] = fmt
    return fmt


def unregister(name: str) -> None:
    """Remove the format ``name`` (tests that register their own)."""
    _REGISTRY.pop(name, None)


def all_formats() -> tuple[Format, ...]:
    """Every registered format, in registration order."""
    return tuple(_REGISTRY.values())


def format_names() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def get_format(name: str) -> Format:
    """The format called ``name``.

    Raises:
        UnsupportedFormatError: no such format.
    """
    try:
        return _REGISTRY[name]
    except KeyError:
        raise UnsupportedFormatError(
            f"format: unknown format '{name}' (fix: use auto or one of {', '.join(_REGISTRY)})") from None


def stored_name(name: str) -> str:
    """The file name the service stores a job's input of the format ``name`` under."""
    return get_format(name).stored_name


def detect_format(path: str | os.PathLike) -> str:
    """The name of the format of ``path``, from its contents (not its extension).

    Raises:
        SurveyValidationError: ``path`` does not exist.
        UnsupportedFormatError: no registered format claims it.
    """
    probe = Probe(path)
    best, claim = None, Claim.NO
    for fmt in _REGISTRY.values():
        c = fmt.sniff(probe)
        if c > claim:
            best, claim = fmt, c
    if best is None:
        what = "folder " if probe.kind == "folder" else ""
        raise UnsupportedFormatError(
            f"file: {what}'{probe.name}' is not a recognised survey (expected "
            f"{'; '.join(f.summary for f in _REGISTRY.values())}) (fix: check that this is the survey "
            "file or folder; write other data as a canonical HDF5 survey; layouts in docs/formats.md)")
    return best.name


def load_survey(path: str | os.PathLike, fmt: str = "auto", *,
                options: FormatOptions | Mapping[str, Any] | None = None, load_samples: bool = True,
                progress: ProgressFn | None = None, **keywords: Any) -> Survey:
    """Load a survey of any registered format.

    Args:
        fmt: "auto" (detect from the contents) or a format name (:func:`format_names`).
        options: the format's options, as its options model or a mapping; ``keywords`` are
            added on top, e.g. ``background=`` (AirSAS CSV), ``image_number=`` (SVSS). Options
            the format does not take are an error naming them.
        load_samples: False reads only metadata and geometry where the format allows.
        progress: ``progress(fraction, stage, metrics)`` for formats read file by file.

    Raises:
        ShsasError: every problem with the file or the options, as one line naming its field.
    """
    try:
        spec = get_format(detect_format(path) if fmt == "auto" else fmt)
        opts = parse_options(spec.name, spec.options, options, keywords)
        return spec.read(Path(path), opts, load_samples, progress or no_progress)
    except ShsasError:
        raise
    except (OSError, RuntimeError, KeyError, ValueError, UnicodeError, EOFError) as exc:
        # safety net: a library error on a malformed file becomes a one-line, named problem
        raise SurveyValidationError(
            "file", f"'{Path(path).name}' could not be read ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0][:160] if str(exc) else 'no detail'})",
            "check that the file is complete and in one of the layouts of docs/formats.md") from None
