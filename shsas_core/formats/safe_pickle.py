"""A restricted unpickler: plain containers and numpy arrays only, never arbitrary code.

A pickle is a small program: every ``GLOBAL``/``STACK_GLOBAL`` opcode names a callable that the
loader imports and calls. :class:`RestrictedUnpickler` overrides ``find_class`` so that only the
names in :data:`ALLOWED_GLOBALS` resolve; anything else (``os.system``, ``builtins.eval``,
``subprocess.Popen``, ``builtins.open`` ...) raises :class:`UnsafeFileError` naming the global
*before* it is called. The allowed callables are either side-effect free constructors or thin,
checked wrappers around numpy's array reconstruction.

The record classes of the AirSAS reference code (``data_schemas.SASDataSchema``, ``SysParams``,
``WfmParams``, ``WfmCropSettings``, ``Geometry``) are mapped to :class:`Record`, an inert holder
of the pickled state, so real processed AirSAS pickles load without importing that code.
"""

from __future__ import annotations

import codecs
import collections
import io
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.common.errors import SurveyValidationError, UnsafeFileError

#: Pickles are read fully into memory; refuse larger files before reading.
MAX_PICKLE_BYTES = 8 * 1024**3
#: numpy's own pickles call ``_reconstruct`` with shape (0,); a large shape is an allocation bomb.
_MAX_RECONSTRUCT_ELEMENTS = 1 << 16


class Record:
    """Inert stand-in for a pickled record object; ``state`` is what the pickle stored."""

    kind = "record"

    def __init__(self) -> None:
        self.state: Any = None

    def __setstate__(self, state: Any) -> None:
        self.state = state

    def data(self) -> dict[str, Any]:
        """The record's fields (the reference code keeps them in ``_data``)."""
        st = self.state
        if isinstance(st, dict):
            inner = st.get("_data", st)
            if isinstance(inner, dict):
                return inner
        return {}


_RECORD_NAMES = ("SASDataSchema", "SysParams", "WfmParams", "WfmCropSettings", "Geometry")
RECORD_TYPES: dict[str, type[Record]] = {
    name: type(name, (Record,), {"kind": name, "__module__": __name__}) for name in _RECORD_NAMES
}


def _reconstruct(subtype: Any, shape: Any, dtype: Any) -> np.ndarray:
    if subtype is not np.ndarray:
        raise UnsafeFileError("pickle", f"array reconstruction of type {subtype!r} is not allowed")
    if int(np.prod(np.asarray(shape, dtype=np.int64))) > _MAX_RECONSTRUCT_ELEMENTS:
        raise UnsafeFileError("pickle", f"array reconstruction with a declared shape {shape} is refused")
    return np.ndarray.__new__(np.ndarray, shape, dtype)


def _frombuffer(buf: Any, dtype: Any, shape: Any, order: str) -> np.ndarray:
    dt = np.dtype(dtype)
    if dt.hasobject:
        raise UnsafeFileError("pickle", "object arrays from raw buffers are refused")
    return np.frombuffer(buf, dtype=dt).reshape(shape, order=order).copy()


def _scalar(dtype: Any, *args: Any) -> Any:
    dt = np.dtype(dtype)
    if dt.hasobject:
        raise UnsafeFileError("pickle", "numpy object scalars are refused")
    from numpy._core.multiarray import scalar  # type: ignore[attr-defined]

    return scalar(dt, *args)


def _encode(text: str, encoding: str = "utf-8") -> bytes:
    # protocol-2 pickles store bytes as _codecs.encode(str, "latin1"); other codecs are refused
    if codecs.lookup(encoding).name not in ("latin-1", "iso8859-1", "utf-8", "ascii"):
        raise UnsafeFileError("pickle", f"_codecs.encode with codec {encoding!r} is refused")
    return codecs.encode(text, encoding)


def _reconstructor(cls: Any, base: Any, state: Any) -> Any:
    # protocol 0/1 form of plain-object creation; only inert records are allowed
    if not (isinstance(cls, type) and issubclass(cls, Record) and base is object and state is None):
        raise UnsafeFileError("pickle", f"copyreg._reconstructor for {cls!r} is refused")
    return cls()


def _allowed() -> dict[tuple[str, str], Any]:
    out: dict[tuple[str, str], Any] = {}
    for name, obj in (("dict", dict), ("list", list), ("tuple", tuple), ("set", set),
                      ("frozenset", frozenset), ("complex", complex), ("bytearray", bytearray),
                      ("bytes", bytes), ("str", str), ("int", int), ("float", float),
                      ("bool", bool), ("slice", slice), ("object", object)):
        out[("builtins", name)] = obj
        out[("__builtin__", name)] = obj
    out[("collections", "OrderedDict")] = collections.OrderedDict
    out[("numpy", "ndarray")] = np.ndarray
    out[("numpy", "dtype")] = np.dtype
    for core in ("numpy.core", "numpy._core"):
        out[(f"{core}.multiarray", "_reconstruct")] = _reconstruct
        out[(f"{core}.multiarray", "scalar")] = _scalar
        out[(f"{core}.numeric", "_frombuffer")] = _frombuffer
    out[("_codecs", "encode")] = _encode
    out[("copyreg", "_reconstructor")] = _reconstructor
    out[("copy_reg", "_reconstructor")] = _reconstructor  # protocol < 3 spelling
    for name, cls in RECORD_TYPES.items():
        out[("data_schemas", name)] = cls
    return out


#: (module, name) -> the object a pickle may refer to. Everything else is refused.
ALLOWED_GLOBALS = _allowed()


class RestrictedUnpickler(pickle.Unpickler):
    """``pickle.Unpickler`` that resolves only :data:`ALLOWED_GLOBALS`."""

    def find_class(self, module: str, name: str) -> Any:
        try:
            return ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise UnsafeFileError(
                "pickle", f"refers to the global '{module}.{name}', which could run code when "
                "loaded; only plain containers and numpy arrays are accepted",
                "export the data as the canonical HDF5 file or a CSV folder instead") from None

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafeFileError("pickle", "uses persistent ids, which are not accepted")


def safe_loads(data: bytes) -> Any:
    """Unpickle ``data`` with :class:`RestrictedUnpickler`; any problem is a SurveyValidationError."""
    try:
        return RestrictedUnpickler(io.BytesIO(data)).load()
    except SurveyValidationError:
        raise
    except MemoryError:
        raise SurveyValidationError("pickle", "declares more data than fits in memory") from None
    except Exception as exc:  # the unpickler raises many types on corrupt input
        raise SurveyValidationError(
            "pickle", f"could not be read ({type(exc).__name__}: {str(exc)[:160]}); "
            "the file may be truncated or not a pickle") from None


def safe_load(path: str | os.PathLike) -> Any:
    """Read and unpickle a file safely (size-capped, restricted globals)."""
    p = Path(path)
    size = p.stat().st_size
    if size > MAX_PICKLE_BYTES:
        raise SurveyValidationError("pickle", f"file is {size} bytes, over the limit of {MAX_PICKLE_BYTES}")
    return safe_loads(p.read_bytes())
