"""`shsas simulate`: writes a readable survey; bad options give one line and exit 2."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.cli import main
from shsas_core.io import read_survey


def test_simulate_writes_survey(tmp_path, capsys):
    out = tmp_path / "s.h5"
    rc = main(["simulate", "--shape", "torus", "--heights", "2", "--angles", "12", "--snr", "10",
               "--seed", "3", "--every", "2", "--specular", "2", "--keep-clean", "--quiet",
               "--out", str(out)])
    assert rc == 0
    s = read_survey(out)
    assert s.num_pings == 12 and s.meta.platform == "simulated" and s.has_ground_truth
    assert "clean" in s.extras and s.meta.attrs["snr_db"] == 10.0
    assert '"specular_weight": 2.0' in s.meta.attrs["config"]
    assert "wrote" in capsys.readouterr().out
    # same options, same bytes
    again = tmp_path / "again.h5"
    main(["simulate", "--shape", "torus", "--heights", "2", "--angles", "12", "--snr", "10",
          "--seed", "3", "--every", "2", "--specular", "2", "--keep-clean", "--quiet",
          "--out", str(again)])
    assert out.read_bytes() == again.read_bytes()


def test_simulate_mesh_file_and_linear(tmp_path):
    from shsas_core.shapes import shape

    mesh = tmp_path / "cube.ply"
    shape("cube").export(mesh)
    out = tmp_path / "lin.h5"
    assert main(["simulate", "--mesh", str(mesh), "--trajectory", "linear", "--heights", "1",
                 "--track-pings", "8", "--no-noise", "--quiet", "--out", str(out)]) == 0
    s = read_survey(out)
    assert s.num_pings == 8 and np.allclose(s.tx[:, 1], -0.85)


@pytest.mark.parametrize("argv,needle", [
    (["--shape", "blob"], "not found"),
    (["--shape", "cube", "--heights", "0"], "--heights"),
    (["--shape", "cube", "--fraction", "1.5"], "--fraction"),
    (["--shape", "cube", "--fs", "50000"], "twice the top chirp"),
    (["--mesh", "/nonexistent/x.obj"], "not found"),
])
def test_bad_options_one_line_exit_2(tmp_path, capsys, argv, needle):
    rc = main(["simulate", *argv, "--quiet", "--out", str(tmp_path / "x.h5")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and needle in err
    assert not (tmp_path / "x.h5").exists()
