"""Error messages never show the server's temporary or data folders."""

from __future__ import annotations

import tempfile

from service.redact import redact_paths


def test_paths_under_the_roots_become_the_file_they_name() -> None:
    tmp = tempfile.gettempdir()
    assert redact_paths(f"cannot read {tmp}/shsas-airsas-x1y2z3ab/scan1/Coordinates.csv: bad") == \
        "cannot read Coordinates.csv: bad"
    assert redact_paths("at /srv/shsas/uploads/ab12/upload.part, byte 9", ["/srv/shsas"]) == \
        "at upload.part, byte 9"
    assert redact_paths(f"'{tmp}/tmpab_cd123' is empty") == "'the archive' is empty"


def test_bare_temporary_folder_names_are_replaced_and_nothing_else() -> None:
    assert redact_paths("file: 'shsas-airsas-txq443tw' holds no AirSAS scan") == \
        "file: 'the archive' holds no AirSAS scan"
    plain = "survey 'scan.h5': pings/tx: has shape (8, 2), expected (8, 3); see /docs and tmpfile"
    assert redact_paths(plain, ["/"]) == plain  # "/" is never taken as a root
