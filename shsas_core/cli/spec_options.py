"""The reconstruction spec as command-line options, generated from ``ReconstructionSpec`` itself.

Every spec field is one option (``--sh-degree`` for ``sh_degree``; a few keep the shorter names
they always had, :data:`OPTION_NAMES`). Its type, choices, bounds, help text and default come from
the spec's JSON schema, the same one the HTTP API publishes, so adding a spec field adds the
option and the CLI cannot disagree with the API or the library on a bound or a default.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from shsas_core.common.errors import ShsasError

#: Spec fields whose option is not ``--{field with - for _}`` (names the CLI has always used).
OPTION_NAMES: dict[str, str] = {"deconvolution": "deconv", "num_bins": "bins", "num_rays": "rays",
                                "holdout_fraction": "holdout"}
#: Placeholders in the help for the options whose value has a name in the docs.
_METAVARS: dict[str, str] = {"sh_degree": "L", "threshold": "TAU", "occupancy": "LEVEL", "occupancy_floor": "FACTOR",
                             "sparsity": "WEIGHT", "angular_prior": "WEIGHT",
                             "tv_density": "WEIGHT", "tv_scatter": "WEIGHT", "tv_phase": "WEIGHT", "holdout_fraction": "FRACTION",
                             "average_last": "FRACTION", "normal_window": "SAMPLES",
                             "coarse_to_fine": "FRACTION"}
#: Given for an optional field (``--occupancy none``): the field's None.
_NONE = "none"


def option_name(field: str) -> str:
    """``--name`` of a spec field's option."""
    return "--" + OPTION_NAMES.get(field, field).replace("_", "-")


def value_schema(prop: dict[str, Any]) -> tuple[dict[str, Any], bool]:
    """(schema of the field's value, whether the field may be None)."""
    alts = prop.get("anyOf")
    if not alts:
        return prop, False
    values = [a for a in alts if a.get("type") != "null"]
    return values[0], len(values) < len(alts)


def bounds_text(value: dict[str, Any]) -> str:
    """``[1, 200000]``, ``(0, 1)``... from the schema's minimum/maximum; '' when unbounded."""
    lo = ("[", value["minimum"]) if "minimum" in value else ("(", value.get("exclusiveMinimum"))
    hi = (value["maximum"], "]") if "maximum" in value else (value.get("exclusiveMaximum"), ")")
    if lo[1] is None and hi[0] is None:
        return ""
    return f"{lo[0]}{'-inf' if lo[1] is None else lo[1]}, {'inf' if hi[0] is None else hi[0]}{hi[1]}"


def _number_or_text(kind: Callable[[str], Any]) -> Callable[[str], Any]:
    """An optional field's value: a number, or ``none``; anything else is passed on as text for the
    spec's validation, which names the option in its one-line error."""

    def convert(text: str) -> Any:
        if text.strip().lower() == _NONE:
            return _NONE
        try:
            return kind(text)
        except ValueError:
            return text

    return convert


_TYPES: dict[str, Callable[[str], Any]] = {"integer": int, "number": float, "string": str}


def add_spec_options(p: argparse.ArgumentParser, exclude: frozenset[str] = frozenset()) -> None:
    """One option per :class:`~shsas_core.spec.job.ReconstructionSpec` field (those in ``exclude``
    aside), plus ``--preset``."""
    from shsas_core.spec.catalogue import DEFAULT_METHODS
    from shsas_core.spec.job import PRESETS, spec_json_schema

    g = p.add_argument_group("reconstruction spec (defaults: shsas_core.spec.job.ReconstructionSpec)")
    g.add_argument("--preset", choices=sorted(PRESETS), default=None,
                   help="start from a named setting: default (the best measured on a CPU) or paper "
                   "(the paper's: empty start, 200 bins x 4,800 rays, paper_gpu encoding, 50k "
                   "iterations; needs a GPU); other options override it")
    for field, prop in spec_json_schema()["properties"].items():
        if field in exclude:
            continue
        value, nullable = value_schema(prop)
        kw: dict[str, Any] = {"default": None, "dest": field, "metavar": _METAVARS.get(field)}
        text = prop.get("description") or value.get("description") or field.replace("_", " ")
        if value.get("type") == "array":  # methods: a comma-separated list of the allowed names
            names = ", ".join(value["items"]["enum"])
            text = f"{text}; comma-separated from {names} (default: {','.join(DEFAULT_METHODS)})"
        else:
            if "enum" in value:
                kw["choices"] = value["enum"]
            kind = _TYPES[value.get("type", "string")]
            kw["type"] = _number_or_text(kind) if nullable else kind
            span = bounds_text(value)
            if span:
                text += f"; in {span}"
            if nullable:
                text += f"; '{_NONE}' = None"
            default = prop.get("default")
            text += f" (default {_NONE if default is None else default})"
        g.add_argument(option_name(field), help=text.replace("%", "%%"), **kw)


def spec_from_args(args: argparse.Namespace, **defaults: object):
    """Build and validate the spec; ``defaults`` apply where an option was not given."""
    import pydantic

    from shsas_core.spec.job import PRESETS, ReconstructionSpec, spec_json_schema

    kw: dict[str, object] = dict(defaults)
    props = spec_json_schema()["properties"]
    kw.update(PRESETS[getattr(args, "preset", None) or "default"])
    for field in ReconstructionSpec.model_fields:
        v = getattr(args, field, None)
        if v is not None:
            kw[field] = None if v == _NONE and value_schema(props[field])[1] else v
    if isinstance(kw.get("methods"), str):
        kw["methods"] = [m.strip() for m in str(kw["methods"]).split(",") if m.strip()]
    try:
        return ReconstructionSpec(**kw)
    except pydantic.ValidationError as exc:
        e = exc.errors()[0]
        field = str(e["loc"][0])
        opt = option_name(field) if field in ReconstructionSpec.model_fields else "--" + field
        raise ShsasError(f"{opt}: {e['msg']} (got {e.get('input')!r})") from None
