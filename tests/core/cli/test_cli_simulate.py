"""`shsas simulate`: writes a readable survey; bad options give one line and exit 2."""

from __future__ import annotations

import numpy as np
import pytest

from shsas_core.cli import main
from shsas_core.formats.hdf5 import read_survey


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
    from shsas_core.simulation.shapes import shape

    mesh = tmp_path / "cube.ply"
    shape("cube").export(mesh)
    out = tmp_path / "lin.h5"
    assert main(["simulate", "--mesh", str(mesh), "--trajectory", "linear", "--heights", "1",
                 "--track-pings", "8", "--no-noise", "--tx-beamwidth", "60", "--rx-beamwidth", "90",
                 "--quiet", "--out", str(out)]) == 0
    s = read_survey(out)
    assert s.num_pings == 8 and np.allclose(s.tx[:, 1], -0.85)
    assert s.meta.tx_beamwidth_deg == 60 and s.meta.rx_beamwidth_deg == 90


def test_simulate_points_file(tmp_path):
    pts = tmp_path / "p.npy"
    np.save(pts, np.array([[0.0, 0.0, 0.05], [0.03, 0.0, 0.1]]))
    out = tmp_path / "p.h5"
    assert main(["simulate", "--points", str(pts), "--heights", "1", "--angles", "4", "--no-noise",
                 "--scene-box", "-0.1", "-0.1", "0", "0.1", "0.1", "0.2", "--quiet",
                 "--out", str(out)]) == 0
    s = read_survey(out)
    assert not s.has_ground_truth and s.meta.attrs["num_scatterers"] == 2
    assert s.meta.scene_box.max == (0.1, 0.1, 0.2)
    bad = tmp_path / "bad.npy"
    np.save(bad, np.zeros((4, 2)))
    assert main(["simulate", "--points", str(bad), "--quiet", "--out", str(out)]) == 2


@pytest.mark.parametrize("argv,needle", [
    (["--shape", "blob"], "not found"),
    (["--shape", "cube", "--heights", "0"], "--heights"),
    (["--shape", "cube", "--fraction", "1.5"], "--fraction"),
    (["--shape", "cube", "--fs", "50000"], "twice the top chirp"),
    (["--mesh", "/nonexistent/x.obj"], "not found"),
    (["--points", "/nonexistent/x.npy"], "not found"),
    (["--shape", "cube", "--tx-beamwidth", "-5"], "--tx-beamwidth"),
    (["--shape", "cube", "--scene-box", "0", "0", "0", "-1", "1", "1"], "--scene-box"),
])
def test_bad_options_one_line_exit_2(tmp_path, capsys, argv, needle):
    rc = main(["simulate", *argv, "--quiet", "--out", str(tmp_path / "x.h5")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and needle in err
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("argv", [["--shape", "cube", "--heights", "many"],
                                  ["--shape", "cube", "--mesh", "a.obj"],
                                  ["--shape", "cube", "--trajectory", "spiral"]])
def test_argparse_errors_are_one_line(tmp_path, capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", *argv, "--out", str(tmp_path / "x.h5")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("shsas simulate: error:")
