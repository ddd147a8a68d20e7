"""Canonical HDF5 survey file: lossless round trip and refusal of unsafe or malformed files."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from shsas_core.common.errors import SurveyValidationError, UnsafeFileError
from shsas_core.formats.hdf5 import read_survey, write_extra, write_survey
from tests.conftest import make_survey


def _arrays(path) -> dict[str, bytes]:
    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda k, o: out.__setitem__(k, o[()].tobytes()) if isinstance(o, h5py.Dataset) else None)
    return out


@pytest.mark.parametrize("complex_", [False, True])
def test_round_trip_is_lossless(tmp_path, complex_):
    s = make_survey(complex_=complex_)
    s.gt_vertices = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0.05]], float)
    s.gt_faces = np.array([[0, 1, 2]])
    s.extras["clean"] = s.samples * 0.5
    a = write_survey(s, tmp_path / "a.h5")
    s2 = read_survey(a)
    b = write_survey(s2, tmp_path / "b.h5")
    assert _arrays(a) == _arrays(b)
    assert s2.meta == s.meta
    assert s2.samples.dtype == s.samples.dtype
    np.testing.assert_array_equal(s2.samples, s.samples)
    np.testing.assert_array_equal(s2.gt_faces, s.gt_faces)
    np.testing.assert_array_equal(s2.extras["clean"], s.extras["clean"])


def test_header_only_read_keeps_shape(tmp_path):
    s = make_survey(n=5, t=300)
    p = write_survey(s, tmp_path / "s.h5")
    h = read_survey(p, load_samples=False)
    assert h.samples is None and h.shape == (5, 300)
    np.testing.assert_array_equal(h.tx, s.tx)


def test_write_extra_appends(tmp_path):
    p = write_survey(make_survey(), tmp_path / "s.h5")
    write_extra(p, "deconvolved", np.ones((8, 512), np.complex64))
    assert read_survey(p).extras["deconvolved"].dtype == np.complex64


def test_external_link_refused(tmp_path):
    p = write_survey(make_survey(), tmp_path / "s.h5")
    with h5py.File(p, "a") as f:
        f["extras/evil"] = h5py.ExternalLink("/etc/passwd.h5", "/x")
    with pytest.raises(UnsafeFileError, match="extras/evil.*external link"):
        read_survey(p)


def test_truncated_file_refused(tmp_path):
    p = write_survey(make_survey(), tmp_path / "s.h5")
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(SurveyValidationError, match="truncated or corrupt"):
        read_survey(p)


def test_subset_keeps_the_ping_counting_attrs_true():
    """A subset used to keep ``attrs.pings_per_level`` of the whole survey."""
    from shsas_core.data.geometry import height_levels
    from tests.helpers.focus_scenes import levels_scene

    s = levels_scene(angles=8, levels=3)
    s.meta = s.meta.model_copy(update={"attrs": {**s.meta.attrs, "height_levels": 3, "pings_per_level": 8}})
    half = s.subset(np.flatnonzero(np.arange(24) % 2 == 0))
    assert half.meta.attrs["pings_per_level"] == 4 and half.meta.attrs["height_levels"] == 3
    low = s.subset(np.flatnonzero(height_levels(s.tx).index == 0))
    assert low.meta.attrs["height_levels"] == 1 and low.meta.attrs["pings_per_level"] == 8
    uneven = s.subset(np.arange(10))
    assert "pings_per_level" not in uneven.meta.attrs
    assert s.meta.attrs["pings_per_level"] == 8  # the original is untouched
