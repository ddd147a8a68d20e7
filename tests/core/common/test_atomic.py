"""The one atomic writer (shsas_core.common.atomic): temporary name, rename, clean-up of partials."""

from __future__ import annotations

import os

import pytest

from shsas_core.common.atomic import atomic_path, is_partial, remove_partials, temporary_name


def test_write_then_rename_leaves_only_the_target(tmp_path):
    target = tmp_path / "sub" / "volume.npy"
    with atomic_path(target) as tmp:
        assert tmp == temporary_name(target) and tmp.parent == target.parent and is_partial(tmp.name)
        tmp.write_bytes(b"data")
        assert not target.exists()  # nothing under the real name until the write is complete
    assert target.read_bytes() == b"data"
    assert sorted(p.name for p in target.parent.iterdir()) == ["volume.npy"]


def test_a_failed_write_keeps_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "report.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("killed")
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["report.json"]


def test_remove_partials_clears_temporaries_of_every_scheme_and_keeps_the_rest(tmp_path):
    (tmp_path / "ckpt").mkdir()
    partial = [temporary_name(tmp_path / "mesh.ply"), tmp_path / "survey.h5.tmp",
               tmp_path / "ckpt" / "checkpoint.pt.tmp123"]
    kept = [tmp_path / "mesh.ply", tmp_path / "notes.tmpl", tmp_path / "ckpt" / "done.json"]
    for p in partial + kept:
        p.write_bytes(b"x")
    remove_partials(tmp_path)
    assert [p.exists() for p in partial] == [False] * 3 and all(p.exists() for p in kept)
    remove_partials(tmp_path / "missing")  # no folder: nothing to do
