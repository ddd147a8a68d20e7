"""Importers against hand-computed values on small synthetic files of each accepted layout."""

from __future__ import annotations

import builtins
import os
import pickle
import zipfile

import numpy as np
import pytest

from shsas_core.common.errors import SurveyValidationError, UnsafeFileError
from shsas_core.formats import detect_format, load_survey
from shsas_core.formats.airsas_csv import parse_waveform_params, read_airsas_csv
from shsas_core.formats.airsas_pickle import read_airsas_pickle
from shsas_core.formats.hdf5 import read_survey, write_survey
from shsas_core.formats.safe_pickle import safe_loads
from shsas_core.formats.svss import read_svss, sound_speed_fresh_water
from tests.helpers.importer_data import FS, AirSASScan, SVSSTrack, lfm, write_airsas_pickle

# --------------------------------------------------------------------------- AirSAS CSV


def test_airsas_csv_geometry_t0_c_pulse_samples(tmp_path):
    scan = AirSASScan()
    folder = scan.write(tmp_path / "scan")
    assert detect_format(folder) == "airsas-csv"
    s = read_airsas_csv(folder)
    # geometry, by hand for the 90° ping: Rz(90)(0.85, 0, 0.30) = (0, 0.85, 0.30)
    np.testing.assert_allclose(s.tx[1], [0.0 - 0.01, 0.85 + 0.02, 0.30 - 0.05], atol=1e-12)
    np.testing.assert_allclose(s.rx[2], [-0.863 - 0.01, 0.0 + 0.02, 0.262 - 0.05 + 0.005], atol=1e-12)
    tx, rx = scan.positions()
    np.testing.assert_allclose(s.tx, tx, atol=1e-12)
    np.testing.assert_allclose(s.rx, rx, atol=1e-12)
    # sound speed from the mean temperature (20..23 °C -> 21.5)
    assert s.meta.sound_speed == pytest.approx(331.4 + 0.6 * 21.5)
    # group delay 12.4 samples: drop 13, first kept sample is 0.6 samples after transmit
    assert s.shape == (4, scan.n_samples - 13)
    np.testing.assert_allclose(s.t0, 0.6 / FS)
    np.testing.assert_array_equal(s.samples, scan.raw()[:, 13:].astype(np.float32))
    # pulse from Waveforms.csv column 0 and parameters from WaveformParams.csv row 1
    np.testing.assert_allclose(s.pulse, lfm(10e3, 30e3, 1e-3, FS, 0.1), rtol=1e-12, atol=1e-15)
    p = s.meta.pulse
    assert (p.f_start, p.f_stop, p.duration, p.window, p.window_param) == (1e4, 3e4, 1e-3, "tukey", 0.1)
    assert s.meta.fs == FS and s.meta.signal_kind == "real" and s.meta.platform == "airsas"
    assert s.meta.scene_box.min == (-0.125, -0.125, 0.0) and s.meta.scene_box.max == (0.125, 0.125, 0.2)


def test_airsas_echo_lands_at_the_true_delay(tmp_path):
    """The point echo, located by correlation, sits at the two-way delay within one sample."""
    scan = AirSASScan()
    s = read_airsas_csv(scan.write(tmp_path / "scan"))
    for i, tau in enumerate(scan.echo_delays()):
        corr = np.correlate(s.samples[i].astype(np.float64), s.pulse, mode="valid")
        t_peak = s.t0[i] + np.argmax(corr) / FS
        assert abs(t_peak - tau) <= 1.0 / FS


def test_airsas_zip_and_background_subtraction(tmp_path):
    scan = AirSASScan()
    folder = scan.write(tmp_path / "scan")
    rng = np.random.default_rng(1)
    room = rng.standard_normal((4, scan.n_samples))
    scan.write(folder / "background", data=room)
    # the scan folder's flights hold echo + room; the background holds the room only
    for i in range(4):
        (folder / f"Flight-{i + 1:06d}.csv").write_text(
            "\n".join(repr(float(v)) for v in scan.raw()[i] + room[i]) + "\n")
    zpath = tmp_path / "scan.zip"
    with zipfile.ZipFile(zpath, "w") as zf:
        for p in sorted(folder.rglob("*")):
            zf.write(p, "myscan/" + str(p.relative_to(folder)))
    assert detect_format(zpath) == "airsas-csv"
    s = load_survey(zpath)
    assert s.meta.attrs["background_subtracted"] is True
    np.testing.assert_allclose(s.samples, scan.raw()[:, 13:], atol=1e-6)
    s_nobg = read_airsas_csv(folder, background=False)
    np.testing.assert_allclose(s_nobg.samples, (scan.raw() + room)[:, 13:], atol=1e-6)


def test_airsas_waveform_selection_and_header_only(tmp_path):
    scan = AirSASScan(angles=[0.0, 0.0, 1.0, 1.0], heights_mm=[0.0] * 4, waveform=[0, 1, 0, 1])
    folder = scan.write(tmp_path / "scan")
    s0 = read_airsas_csv(folder)
    assert s0.num_pings == 2 and s0.meta.pulse.f_start == 1e4
    s1 = read_airsas_csv(folder, waveform=1)
    assert s1.num_pings == 2 and (s1.meta.pulse.f_start, s1.meta.pulse.f_stop) == (17.5e3, 22.5e3)
    np.testing.assert_allclose(s1.pulse, lfm(17.5e3, 22.5e3, 1e-3, FS, 0.1), atol=1e-15)
    np.testing.assert_array_equal(s1.samples, scan.raw()[[1, 3], 13:].astype(np.float32))
    h = load_survey(folder, load_samples=False)
    assert h.samples is None and h.shape == s0.shape
    np.testing.assert_array_equal(h.tx, s0.tx)
    sa = read_airsas_csv(folder, pulse="analytic")
    np.testing.assert_allclose(sa.pulse, s0.pulse, atol=1e-12)


def test_airsas_integer_group_delay_gives_t0_zero_and_round_trips(tmp_path):
    scan = AirSASScan(gd=10.0, header=False)
    s = read_airsas_csv(scan.write(tmp_path / "scan"))
    assert np.all(s.t0 == 0.0) and s.num_samples == scan.n_samples - 10
    s2 = read_survey(write_survey(s, tmp_path / "s.h5"))
    np.testing.assert_array_equal(s2.samples, s.samples)
    assert s2.meta == s.meta


@pytest.mark.parametrize(("text", "expect"), [
    ("LFM_1.000E+4Hz_3.000E+4Hz_1.000E-3s_1.000E+0_1.000E+0_1.000E-1", (1e4, 3e4, 1e-3, 0.1)),
    ("20000_30000_0.002_0.25", (2e4, 3e4, 2e-3, 0.25)),
])
def test_waveform_params_forms(text, expect):
    p = parse_waveform_params(text, 1)
    assert (p.f_start, p.f_stop, p.duration, p.window_param) == expect


# --------------------------------------------------------------------------- AirSAS pickle


@pytest.mark.parametrize("protocol", [1, 2, 4, 5])
def test_airsas_pickle_reference_layout(tmp_path, protocol):
    scan = AirSASScan()
    path = tmp_path / "system_data.pik"
    v = write_airsas_pickle(path, scan, protocol=protocol)
    assert detect_format(path) == "airsas-pickle" or protocol < 2
    s = read_airsas_pickle(path)
    np.testing.assert_array_equal(s.samples, v["wfm_data"].astype(np.float32))
    np.testing.assert_array_equal(s.tx, v["tx_coords"])
    np.testing.assert_array_equal(s.rx, v["rx_coords"])
    assert np.all(s.t0 == 0.0)
    assert s.meta.sound_speed == pytest.approx(331.4 + 0.6 * 21.5)
    assert s.meta.fs == FS and s.meta.pulse.f_stop == 3e4 and s.meta.pulse.window_param == 0.1
    np.testing.assert_array_equal(s.pulse, v["wfm"])
    assert s.meta.scene_box.min == (-0.2, -0.2, 0.0) and s.meta.scene_box.max == (0.2, 0.2, 0.3)


class _MakesFile:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (builtins.open, (str(self.target), "w"))


class _RunsShell:
    def __init__(self, target):
        self.target = target

    def __reduce__(self):
        return (os.system, (f"touch '{self.target}'",))


@pytest.mark.parametrize("evil_cls", [_MakesFile, _RunsShell])
def test_code_executing_pickle_is_refused_and_never_run(tmp_path, evil_cls):
    target = tmp_path / "pwned"
    data = pickle.dumps({"wfm_data": np.zeros((2, 3)), "x": evil_cls(target)})
    with pytest.raises(UnsafeFileError) as ei:
        safe_loads(data)
    assert not target.exists()
    name = f"{builtins.open.__module__}.open" if evil_cls is _MakesFile else f"{os.system.__module__}.system"
    assert name in str(ei.value)
    # the plain loader would have run it: the test payload is real
    pickle.loads(data)
    assert target.exists()


def test_unpickler_allows_numpy_and_containers_only():
    obj = {"a": [1, 2.5, (3, "x")], "b": np.arange(6, dtype=np.int32).reshape(2, 3),
           "c": np.float64(1.5), "d": {1, 2}, "e": b"bytes", "f": np.array([1 + 2j])}
    for proto in (1, 2, 4, 5):
        out = safe_loads(pickle.dumps(obj, protocol=proto))
        np.testing.assert_array_equal(out["b"], obj["b"])
        assert out["a"] == obj["a"] and out["c"] == 1.5 and out["d"] == {1, 2} and out["e"] == b"bytes"
    with pytest.raises(UnsafeFileError, match="collections.Counter"):
        import collections

        safe_loads(pickle.dumps(collections.Counter("ab")))


# --------------------------------------------------------------------------- SVSS


def test_svss_geometry_samples_and_parameters(tmp_path):
    tr = SVSSTrack()
    folder = tr.write(tmp_path)
    assert detect_format(folder) == "svss"
    s = read_svss(folder)
    assert s.shape == (12, 256)
    re_, im = tr.data()
    np.testing.assert_array_equal(s.samples, (re_ + 1j * im).astype(np.complex64))
    assert np.all(s.t0 == 0)
    m = s.meta
    assert (m.fs, m.carrier_hz, m.signal_kind) == (125e3, 27.5e3, "baseband")
    assert (m.tx_beamwidth_deg, m.rx_beamwidth_deg) == (25.0, 50.0)
    assert (m.pulse.f_start, m.pulse.f_stop, m.pulse.duration, m.pulse.window) == (35e3, 20e3, 255e-6, "taylor")
    # 60 °F = 15.556 °C: 1404.3 + 4.7·15.556 − 0.04·15.556² = 1467.73 m/s
    assert m.sound_speed == pytest.approx(1467.732, abs=1e-3)
    # second <kernel> block of the XML is the pulse
    np.testing.assert_array_equal(s.pulse, [1.0, 0.5 - 0.5j, 0.25 + 0.25j])
    # ping 0 (firing 0, no attitude): TX element 0 at Position, flipped to z up
    np.testing.assert_allclose(s.tx[0], [0.0, -1.0, -0.5])
    np.testing.assert_allclose(s.rx[2], [0.0, -(1.0 + 0.1), -(0.5 + 0.02)])
    # firing 1 (rows 3..5) uses TX element 1 and yaw 90°: A·(x, y, z) = (y, −x, z)
    np.testing.assert_allclose(s.tx[3], [0.1 + 0.05, -(1.0 - 0.1), -0.5], atol=1e-12)
    np.testing.assert_allclose(s.rx[5], [0.1 + 0.1, -(1.0 - 0.0), -(0.5 + 0.02)], atol=1e-12)
    # firing 2 wraps back to TX element 0
    np.testing.assert_allclose(s.tx[6], [0.2, -1.01, -0.51])
    # beams point down (+z in the depth-positive SVSS frame, -z in the z-up frame)
    np.testing.assert_allclose(s.tx_dir, np.tile([0.0, 0.0, -1.0], (12, 1)), atol=1e-12)


def test_svss_attitude_roll_pitch_against_rotation_composition(tmp_path):
    """The attitude matrix equals R_x(roll)·R_y(pitch)·R_z(yaw) written out independently."""
    from shsas_core.formats.svss import attitude_matrix

    r, p, y = 0.1, -0.2, 0.3

    def rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])

    def ry(a):
        return np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])

    def rz(a):
        return np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])

    np.testing.assert_allclose(attitude_matrix(np.array([r]), np.array([p]), np.array([y]))[0],
                               rx(r) @ ry(p) @ rz(y), atol=1e-14)


def test_svss_unpack_file_path_default_temperature_and_analytic_pulse(tmp_path):
    tr = SVSSTrack(temperature_f=None, kernel=False)
    folder = tr.write(tmp_path)
    unpack = folder / f"unpack float - LF - down - {tr.number}.hdf5"
    assert detect_format(unpack) == "svss"
    s = load_survey(unpack, load_samples=False)
    assert s.samples is None and s.shape == (12, 256)
    assert s.meta.sound_speed == pytest.approx(sound_speed_fresh_water(55.0))
    assert sound_speed_fresh_water(32.0) == pytest.approx(1404.3)
    # analytic pulse: hilbert(Taylor-windowed 35 -> 20 kHz LFM) · exp(-2πi·27.5 kHz·t)
    from scipy.signal import hilbert, windows

    n = round(255e-6 * 125e3)
    t = np.arange(n) / 125e3
    real = np.cos(2 * np.pi * (35e3 * t + 0.5 * (20e3 - 35e3) / 255e-6 * t * t)) * windows.taylor(n, sll=40)
    np.testing.assert_allclose(s.pulse, hilbert(real) * np.exp(-2j * np.pi * 27.5e3 * t), atol=1e-12)
    spec = np.abs(np.fft.fft(s.pulse, 4096)) ** 2
    f = np.fft.fftfreq(4096, 1 / 125e3)
    assert abs(np.sum(f * spec) / np.sum(spec)) < 1.5e3  # centred on 0 Hz after basebanding
    s2 = read_svss(folder, temperature_f=40.0, load_samples=False)
    assert s2.meta.sound_speed == pytest.approx(1404.3 + 4.7 * (8 * 5 / 9) - 0.04 * (8 * 5 / 9) ** 2)


def test_svss_missing_motion_file_named(tmp_path):
    tr = SVSSTrack()
    folder = tr.write(tmp_path)
    (folder / f"motion solution - LF - down - {tr.number}.hdf5").unlink()
    with pytest.raises(SurveyValidationError, match="motion solution - LF - down - 7.hdf5"):
        read_svss(folder)


# --------------------------------------------------------------------------- zip safety


def _zip_scan(folder, z, extra=()):
    """Zip ``folder``'s files under ``scan/``, plus (name, bytes) ``extra`` members."""
    with zipfile.ZipFile(z, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for p in sorted(folder.iterdir()):
            if p.is_file():
                zf.write(p, f"scan/{p.name}")
        for name, data in extra:
            zf.writestr(name, data)
    return z


def test_safe_zip_total_size_budget_from_the_central_directory(tmp_path):
    from shsas_core.formats.safe_zip import SafeZip

    z = tmp_path / "big.zip"
    with zipfile.ZipFile(z, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("scan/Flight-000001.csv", "0.0\n" * 10_000)  # 40 kB, compresses to ~100 B
    with pytest.raises(UnsafeFileError, match="zip bomb"):
        SafeZip(z, max_bytes=1_000)
    archive = SafeZip(z, max_bytes=100_000)
    assert archive.read(("scan", "Flight-000001.csv"), 40_000) == b"0.0\n" * 10_000
    with pytest.raises(SurveyValidationError, match="over the limit of 39999"):
        archive.read(("scan", "Flight-000001.csv"), 39_999)
    archive.close()


def test_safe_zip_member_count_read_before_the_directory(tmp_path):
    from shsas_core.formats.safe_zip import SafeZip, declared_entries

    z = tmp_path / "many.zip"
    with zipfile.ZipFile(z, "w") as zf:
        for i in range(50):
            zf.writestr(f"scan/f{i}.csv", "1\n")
    assert declared_entries(z) == 50
    with pytest.raises(UnsafeFileError, match="50 members, over the limit of 10"):
        SafeZip(z, max_members=10)
    (tmp_path / "cut.zip").write_bytes(z.read_bytes()[:-30])  # end record cut off
    with pytest.raises(SurveyValidationError, match="end-of-central-directory"):
        declared_entries(tmp_path / "cut.zip")


@pytest.mark.parametrize("name", ["/etc/evil.csv", "a/../../evil.csv", "C:/evil.csv", "..\\evil.csv"])
def test_safe_zip_refuses_escaping_names(tmp_path, name):
    from shsas_core.formats.safe_zip import SafeZip

    z = tmp_path / "t.zip"
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("ok.csv", "1\n")
        zf.writestr(name, "x")
    with pytest.raises(UnsafeFileError, match="path traversal"):
        SafeZip(z)


def test_safe_zip_refuses_symlinks(tmp_path):
    from shsas_core.formats.safe_zip import SafeZip

    z = tmp_path / "t.zip"
    info = zipfile.ZipInfo("scan/Coordinates.csv")
    info.external_attr = (0o120777 << 16)  # S_IFLNK
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr(info, "/etc/passwd")
    with pytest.raises(UnsafeFileError, match="symbolic link"):
        SafeZip(z)


def test_zip_reads_only_the_members_the_scan_needs(tmp_path):
    """A member the scan does not name is never decompressed: here one whose data is corrupt
    (reading it would fail its CRC check), beside a valid scan, loads fine and equals the folder."""
    folder = AirSASScan().write(tmp_path / "scan")
    z = _zip_scan(folder, tmp_path / "scan.zip", extra=[("scan/notes/junk.bin", b"\0" * 1_000_000)])
    raw = bytearray(z.read_bytes())
    with zipfile.ZipFile(z) as zf:
        info = zf.getinfo("scan/notes/junk.bin")
    body = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    raw[body:body + 50] = b"\xff" * 50
    z.write_bytes(bytes(raw))
    with zipfile.ZipFile(z) as zf, pytest.raises(Exception):  # noqa: B017 - zipfile raises zlib.error or BadZipFile
        zf.read("scan/notes/junk.bin")
    from_zip, from_folder = load_survey(z), load_survey(folder)
    np.testing.assert_array_equal(from_zip.samples, from_folder.samples)
    np.testing.assert_array_equal(from_zip.tx, from_folder.tx)


def test_background_at_other_positions_is_refused(tmp_path):
    scan = AirSASScan()
    folder = scan.write(tmp_path / "scan")
    AirSASScan(angles=[0.0, 90.0, 180.0, 271.0]).write(folder / "background")
    with pytest.raises(SurveyValidationError, match=r"background: .*ping 4 is at angle 271"):
        read_airsas_csv(folder)


def test_zip_is_never_extracted(tmp_path, monkeypatch):
    """Reading an AirSAS zip (all samples, then the header only, then a refused one) writes
    nothing under TMPDIR."""
    import tempfile

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    good = _zip_scan(AirSASScan().write(tmp_path / "scan"), tmp_path / "good.zip")
    assert load_survey(good).num_pings == 4
    assert load_survey(good, load_samples=False).shape == (4, 1200 - 13)
    bad = tmp_path / "bad.zip"
    with zipfile.ZipFile(bad, "w") as zf:
        zf.writestr("../x.csv", "1")
    with pytest.raises(UnsafeFileError):
        load_survey(bad)
    assert list(tmp.iterdir()) == []


def test_zipped_deconvolved_and_svss_folders_read_like_the_folders(tmp_path):
    """The two other folder formats read from a zip equal the folder read (format detected
    from the member names)."""
    track = SVSSTrack().write(tmp_path / "svss")
    z = tmp_path / "track.zip"
    with zipfile.ZipFile(z, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for p in track.iterdir():
            zf.write(p, f"{track.name}/{p.name}")
    assert detect_format(z) == "svss"
    a, b = load_survey(z), load_survey(track)
    np.testing.assert_array_equal(a.samples, b.samples)
    np.testing.assert_array_equal(a.tx, b.tx)
    assert a.meta == b.meta
    dec = tmp_path / "dec"
    dec.mkdir()
    rng = np.random.default_rng(0)
    for k in range(2):
        np.save(dec / f"weights_trans_{4 * k}_{4 * k + 3}.npy", rng.standard_normal((4, 608)).astype(np.float16))
    z = tmp_path / "dec.zip"
    with zipfile.ZipFile(z, "w") as zf:
        for p in dec.iterdir():
            zf.write(p, f"dec/{p.name}")
    assert detect_format(z) == "airsas-deconvolved"
    a, b = load_survey(z), load_survey(dec)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.shape == (8, 608) and a.meta.fs == b.meta.fs


def test_progress_reaches_one_for_csv_import(tmp_path):
    calls = []
    load_survey(AirSASScan().write(tmp_path / "scan"), progress=lambda f, st, m: calls.append((f, st)))
    assert calls[-1] == (1.0, "import:airsas") and all(0 <= f <= 1 for f, _ in calls)
