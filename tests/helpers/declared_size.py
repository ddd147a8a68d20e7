"""Survey files that declare far more samples than their size suggests (memory bombs).

Both start from a valid tiny survey and replace ``pings/samples`` with a float32 dataset of the
declared shape, one chunk per ping:

- :func:`unwritten_samples`: chunks never written (they read as the fill value); the issue's
  0.7 MB file declaring (360, 1,000,000).
- :func:`zero_filled_samples`: every chunk allocated and written by HDF5 itself with a deflated
  fill value (early allocation), so the file is well formed but a few MB declare up to 16 GB.
"""

from __future__ import annotations

from pathlib import Path

import h5py

from shsas_core.formats.hdf5 import write_survey
from tests.conftest import make_survey


def _base(path: Path, n: int) -> None:
    # 512 samples reach the default scene box; the real width is set below.
    write_survey(make_survey(n=n, t=512), path)


def unwritten_samples(path: Path, n: int, t: int) -> Path:
    _base(path, n)
    with h5py.File(path, "a") as f:
        del f["pings/samples"]
        f["pings"].create_dataset("samples", shape=(n, t), dtype="f4", chunks=(1, min(t, 65536)))
    return path


def zero_filled_samples(path: Path, n: int, t: int) -> Path:
    _base(path, n)
    with h5py.File(path, "a") as f:
        del f["pings/samples"]
        dcpl = h5py.h5p.create(h5py.h5p.DATASET_CREATE)
        dcpl.set_chunk((1, t))
        dcpl.set_deflate(9)
        dcpl.set_alloc_time(h5py.h5d.ALLOC_TIME_EARLY)
        dcpl.set_fill_time(h5py.h5d.FILL_TIME_ALLOC)
        h5py.h5d.create(f["pings"].id, b"samples", h5py.h5t.NATIVE_FLOAT, h5py.h5s.create_simple((n, t)), dcpl=dcpl)
    return path
