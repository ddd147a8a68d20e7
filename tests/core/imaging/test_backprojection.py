"""Backprojection: point-target focus, range resolution, brute-force equality, chunking, I/O."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import scipy.signal
import torch

from shsas_core.common.errors import Cancelled, ShsasError
from shsas_core.data.survey import SceneBox, Survey, SurveyMeta, default_pulse
from shsas_core.data.volume import Grid
from shsas_core.imaging._backprojection_reference import reference_backproject
from shsas_core.imaging.backprojection import (
    BackprojectionConfig,
    Beams,
    backproject,
    backproject_survey,
    default_signals,
    upsample_signals,
)
from shsas_core.signal.chain import baseband, matched_filter
from shsas_core.signal.deconv import DeconvConfig, deconvolve
from tests.helpers.echoes import point_echoes

EAGER = BackprojectionConfig(backend="eager")


def brute_force(signals, tx, rx, t0, fs, c, points, carrier_hz=None, beams=None, nearest=False):
    """Python loop over voxels and pings, float64: the definition of backprojection."""
    n, t = signals.shape
    out = np.zeros(len(points), complex)
    for v, x in enumerate(points):
        for i in range(n):
            dt, dr = np.linalg.norm(x - tx[i]), np.linalg.norm(x - rx[i])
            if beams is not None:
                if beams.tx_dir is not None:
                    u = beams.tx_dir[i] / np.linalg.norm(beams.tx_dir[i])
                    if np.dot(x - tx[i], u) < math.cos(beams.tx_half_angle) * dt:
                        continue
                if beams.rx_dir is not None:
                    u = beams.rx_dir[i] / np.linalg.norm(beams.rx_dir[i])
                    if np.dot(x - rx[i], u) < math.cos(beams.rx_half_angle) * dr:
                        continue
            d = dt + dr
            k = (d / c - t0[i]) * fs
            if k < 0 or k > t - 1:
                continue
            if nearest:
                val = signals[i, math.floor(k)]
            else:
                k0 = min(math.floor(k), t - 2)
                w = k - k0
                val = signals[i, k0] * (1 - w) + signals[i, k0 + 1] * w
            if carrier_hz is not None:
                val = val * np.exp(2j * np.pi * carrier_hz * d / c)
            out[v] += val
    return out


def _random_case(seed=0, n=7, t=300, v=40):
    rng = np.random.default_rng(seed)
    sig = (rng.standard_normal((n, t)) + 1j * rng.standard_normal((n, t))).astype(np.complex64)
    ang = rng.uniform(0, 2 * np.pi, n)
    tx = np.stack([0.9 * np.cos(ang), 0.9 * np.sin(ang), rng.uniform(0.2, 0.4, n)], 1)
    rx = tx + np.array([0.013, 0.0, -0.038])
    t0 = rng.uniform(3e-3, 4e-3, n)
    pts = rng.uniform(-0.15, 0.15, (v, 3)) + np.array([0, 0, 0.1])
    return sig, tx, rx, t0, 100e3, 343.0, pts


@pytest.mark.parametrize("carrier", [None, 20e3])
@pytest.mark.parametrize("nearest", [False, True])
@pytest.mark.parametrize("backend, device", [("eager", "cpu"),
                                             pytest.param("triton", "cuda", marks=pytest.mark.gpu)])
def test_fast_path_matches_brute_force(carrier, nearest, backend, device):
    # small enough that no (voxel, ping) pair sits within float32 rounding of a sample edge,
    # where nearest interpolation would jump (the eager and Triton kernels round differently)
    sig, tx, rx, t0, fs, c, pts = _random_case()
    cfg = BackprojectionConfig(backend=backend, interpolation="nearest" if nearest else "linear",
                               ping_chunk=3, voxel_block=16)
    got = backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=carrier, config=cfg, device=device)
    ref = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts, carrier, nearest=nearest)
    assert np.count_nonzero(ref) > len(pts) // 2  # the case exercises real data, not zeros
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()


def test_beam_cones_match_brute_force():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=3, n=9, v=60)
    centre = np.array([0.0, 0.0, 0.1])
    rng = np.random.default_rng(5)
    tdir = centre - tx + rng.normal(0, 0.1, tx.shape)
    rdir = centre - rx + rng.normal(0, 0.1, rx.shape)
    beams = Beams(tdir, rdir, math.radians(10), math.radians(14))
    got = backproject(sig, tx, rx, t0, fs, c, pts, beams=beams, config=EAGER)
    ref = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts, beams=beams)
    full = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts)
    assert not np.allclose(ref, full)  # the cones do cut some (voxel, ping) pairs
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()


def test_plain_reference_agrees_with_brute_force_and_fast_path():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=1, n=20, v=300)
    ref = reference_backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=20e3, ping_chunk=6,
                                dtype=torch.float64)
    brute = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts[:30], 20e3)
    np.testing.assert_allclose(ref[:30], brute, atol=1e-9 * np.abs(brute).max())
    got = backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=20e3, config=EAGER)
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()


def test_chunk_sizes_do_not_change_the_result():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=2, n=13, v=101)
    a = backproject(sig, tx, rx, t0, fs, c, pts, config=BackprojectionConfig(backend="eager", ping_chunk=13, voxel_block=1000))
    b = backproject(sig, tx, rx, t0, fs, c, pts, config=BackprojectionConfig(backend="eager", ping_chunk=4, voxel_block=17))
    np.testing.assert_allclose(a, b, atol=1e-5 * np.abs(a).max())


@pytest.mark.slow
def test_compiled_kernel_matches_brute_force():
    # a fresh compile: earlier tests in this process compiled the kernel for other shapes, and
    # past dynamo's recompile limit (8) the explicit "compiled" backend raises instead of compiling
    torch._dynamo.reset()
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=4, n=10, v=50)
    cfg = BackprojectionConfig(backend="compiled", ping_chunk=4, voxel_block=32)
    got = backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=20e3, config=cfg)
    ref = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts, 20e3)
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()


@pytest.mark.slow
def test_compiled_kernel_serves_many_record_lengths_in_one_process():
    # a long-lived worker sees surveys of many record lengths; compiled for each length, the
    # kernel would pass dynamo's recompile limit (8) at the ninth and stop compiling
    torch._dynamo.reset()
    cfg = BackprojectionConfig(backend="compiled", ping_chunk=4, voxel_block=32)
    for t in range(200, 200 + 10 * 17, 17):
        sig, tx, rx, t0, fs, c, pts = _random_case(seed=t, n=6, t=t, v=40)
        got = backproject(sig, tx, rx, t0, fs, c, pts, config=cfg)
        ref = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts)
        assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max(), t


@pytest.mark.gpu
def test_cuda_matches_cpu():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=6, n=32, v=500)
    cpu = backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=20e3, config=EAGER)
    for backend in ("eager", "compiled", "triton", "auto"):
        gpu = backproject(sig, tx, rx, t0, fs, c, pts, carrier_hz=20e3,
                          config=BackprojectionConfig(backend=backend), device="cuda")
        assert np.abs(gpu - cpu).max() <= 1e-4 * np.abs(cpu).max()


@pytest.mark.gpu
def test_triton_kernel_beam_cones_match_brute_force():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=3, n=9, v=60)
    centre = np.array([0.0, 0.0, 0.1])
    rng = np.random.default_rng(5)
    beams = Beams(centre - tx + rng.normal(0, 0.1, tx.shape), centre - rx + rng.normal(0, 0.1, rx.shape),
                  math.radians(10), math.radians(14))
    got = backproject(sig, tx, rx, t0, fs, c, pts, beams=beams, device="cuda",
                      config=BackprojectionConfig(backend="triton"))
    ref = brute_force(sig.astype(np.complex128), tx, rx, t0, fs, c, pts, beams=beams)
    assert np.abs(got - ref).max() <= 1e-4 * np.abs(ref).max()


def test_triton_backend_off_cuda_is_a_clear_error():
    sig, tx, rx, t0, fs, c, pts = _random_case(seed=8, n=4, v=10)
    with pytest.raises(ShsasError, match="triton.*CUDA"):
        backproject(sig, tx, rx, t0, fs, c, pts, config=BackprojectionConfig(backend="triton"))


def test_cli_backend_choices_are_the_configs():
    from typing import get_args

    from shsas_core.cli import build_parser

    sub = build_parser()._subparsers._group_actions[0].choices["backproject"]
    action = next(a for a in sub._actions if a.dest == "backend")
    assert list(action.choices) == list(get_args(BackprojectionConfig.model_fields["backend"].annotation))


def test_upsample_signals_is_band_limited_interpolation():
    rng = np.random.default_rng(0)
    for t in (64, 65):
        x = rng.standard_normal((3, t)) + 1j * rng.standard_normal((3, t))
        up = upsample_signals(torch.as_tensor(x), 4).numpy()
        np.testing.assert_allclose(up[:, ::4], x, atol=1e-9)
        np.testing.assert_allclose(up, scipy.signal.resample(x, 4 * t, axis=-1), atol=1e-9)


# ---------------------------------------------------------------------------- imaging physics

def _helix_survey(targets, n=120, t=420, heights=(0.15, 0.3, 0.45), signal="real"):
    meta = SurveyMeta(fs=100e3, platform="test")
    per = n // len(heights)
    ang = np.tile(np.linspace(0, 2 * np.pi, per, endpoint=False), len(heights))
    z = np.repeat(heights, per)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), z], 1)
    rx = np.stack([0.863 * np.cos(ang), 0.863 * np.sin(ang), z - 0.038], 1)
    t0 = np.full(len(tx), 4e-3)
    x = point_echoes(default_pulse(meta), tx, rx, t0, t, meta.fs, meta.sound_speed, targets)
    return Survey(tx=tx, rx=rx, samples=x, t0=t0, meta=meta, pulse=default_pulse(meta))


@pytest.mark.parametrize("demodulate", [True, False])
@pytest.mark.parametrize("signal", ["wiener", "matched"])
def test_point_target_focuses_within_half_a_voxel(demodulate, signal):
    grid = Grid((-0.04, -0.04, 0.0), (0.04, 0.04, 0.08), (16, 16, 16))  # 5 mm voxels
    centres = grid.points().reshape(*grid.shape, 3)
    target = centres[9, 6, 7] + np.array([0.0012, -0.0009, 0.0007])  # off-centre, < half a voxel
    s = _helix_survey(target[None])
    sig = deconvolve(s, DeconvConfig()) if signal == "wiener" else matched_filter(s)
    cfg = BackprojectionConfig(backend="eager", demodulate=demodulate)
    vol = backproject_survey(s, grid, sig, config=cfg)
    mag = np.abs(vol.values)
    peak = np.unravel_index(np.argmax(mag), grid.shape)
    assert tuple(int(i) for i in peak) == (9, 6, 7)
    assert np.all(np.abs(centres[peak] - target) <= 0.5 * grid.spacing)
    # focused: the peak stands well above the image's median
    assert mag.max() > 10 * np.median(mag)


def _range_pair(sep, signals_fn):
    """Two equal targets `sep` apart along x, sensors on a ±15° arc on the -x side (range ≈ x)."""
    meta = SurveyMeta(fs=100e3, platform="test",
                      scene_box=SceneBox(min=(-0.05, -0.05, 0.0), max=(0.05, 0.05, 0.2)))
    ang = np.radians(np.linspace(-15, 15, 31)) + np.pi
    tx = np.stack([np.cos(ang), np.sin(ang), np.full(31, 0.1)], 1)
    rx = tx * [1.01, 1.01, 1.0]
    t0 = np.full(31, 5e-3)
    targets = np.array([[-sep / 2, 0, 0.1], [sep / 2, 0, 0.1]])
    # Scatterers in phase quadrature: the intensities add as for incoherent targets (Rayleigh's
    # setting). An in-phase pair exactly c/2B apart merges for any sinc-like PSF, because with
    # f_c/B = 1 the two-way phase difference is exactly 2π.
    x = point_echoes(default_pulse(meta), tx, rx, t0, 400, meta.fs, meta.sound_speed, targets,
                     amps=np.array([1.0, 1j]))
    s = Survey(tx=tx, rx=rx, samples=x, t0=t0, meta=meta, pulse=default_pulse(meta))
    xs = np.linspace(-0.02, 0.02, 161)
    pts = np.stack([xs, np.zeros_like(xs), np.full_like(xs, 0.1)], 1)
    fc = meta.pulse.f_center
    sig = baseband(signals_fn(s), t0, meta.fs, fc)
    img = np.abs(backproject(sig, tx, rx, t0, meta.fs, meta.sound_speed, pts, carrier_hz=fc, config=EAGER))
    return xs, img


@pytest.mark.parametrize(("method", "cells"), [("matched", 1.0), ("wiener-rect", 1.0), ("wiener", 1.5)])
def test_targets_one_range_resolution_apart_are_resolved(method, cells):
    """A pair `cells` x c/2B apart shows two peaks at the targets with a dip between them.

    For a sinc-like response the dip at exactly c/2B (Rayleigh) is ~0.9 dB; the default
    Taylor-tapered Wiener filter trades a ~1.5x wider main lobe for -34 dB sidelobes (the matched
    filter has -14 dB), so it is checked at 1.5 c/2B (at 1.4 c/2B it shows no dip).
    """
    sep = cells * 343.0 / (2 * 20e3)  # c / 2B = 8.6 mm
    fns = {"matched": matched_filter,
           "wiener-rect": lambda s: deconvolve(s, DeconvConfig(taper="rect")),
           "wiener": lambda s: deconvolve(s, DeconvConfig())}
    xs, img = _range_pair(sep, fns[method])
    left = img[xs < 0].max()
    right = img[xs > 0].max()
    xl, xr = xs[xs < 0][np.argmax(img[xs < 0])], xs[xs > 0][np.argmax(img[xs > 0])]
    assert abs(xl + sep / 2) < 1.5e-3 and abs(xr - sep / 2) < 1.5e-3  # peaks at the targets
    between = img[(xs > xl) & (xs < xr)].min()
    dip_db = 20 * np.log10(between / min(left, right))
    assert dip_db < -0.5, f"{method}: dip between the targets only {dip_db:.2f} dB"


def test_backproject_survey_defaults():
    s = _helix_survey(np.array([[0.0, 0.0, 0.04]]), n=30)
    _, name = default_signals(s)
    assert name == "matched"
    s.extras["deconvolved"] = deconvolve(s)
    assert default_signals(s)[1] == "deconvolved"
    grid = Grid((-0.02, -0.02, 0.02), (0.02, 0.02, 0.06), (8, 8, 8))
    calls = []
    vol = backproject_survey(s, grid, config=BackprojectionConfig(backend="eager", voxel_block=100),
                             progress=lambda f, st, m: calls.append(f))
    assert vol.values.shape == (8, 8, 8) and vol.values.dtype == np.complex64
    assert calls[-1] == pytest.approx(1.0) and len(calls) > 1


def test_cancel_and_bad_input():
    sig, tx, rx, t0, fs, c, pts = _random_case()
    with pytest.raises(Cancelled):
        backproject(sig, tx, rx, t0, fs, c, pts, config=EAGER, should_stop=lambda: True)
    with pytest.raises(ShsasError, match="complex"):
        backproject(sig.real, tx, rx, t0, fs, c, pts, config=EAGER)
    with pytest.raises(ShsasError, match="points"):
        backproject(sig, tx, rx, t0, fs, c, pts[:, :2], config=EAGER)
    with pytest.raises(ShsasError, match="tx/rx"):
        backproject(sig, tx[:3], rx, t0, fs, c, pts, config=EAGER)
    assert backproject(sig, tx, rx, t0, fs, c, np.zeros((0, 3)), config=EAGER).shape == (0,)


def test_cli_backproject_writes_volume(tmp_path, capsys):
    from shsas_core.cli import main
    from shsas_core.formats.hdf5 import write_survey
    from shsas_core.outputs.export import read_volume_npy

    grid = Grid.over(SceneBox(), 16)
    centres = grid.points().reshape(*grid.shape, 3)
    target = centres[5, 9, 4]
    s = _helix_survey(target[None], n=60, t=500)
    path = write_survey(s, tmp_path / "s.h5")
    rc = main(["backproject", str(path), "--grid", "16", "--out", str(tmp_path / "bp"), "--quiet",
               "--backend", "eager"])
    assert rc == 0
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["peak_voxel"] == [5, 9, 4] and out["signal"] == "wiener deconvolution"
    # the volume format of `shsas reconstruct`: NPY + JSON sidecar with the grid and the settings
    vol = read_volume_npy(tmp_path / "bp" / "volume.npy")
    assert vol.grid.shape == grid.shape and vol.values.dtype == np.complex64
    assert vol.grid.box_min == grid.box_min and vol.name == "backprojection"
    info = json.loads((tmp_path / "bp" / "volume.json").read_text())
    assert info["shape"] == list(grid.shape) and info["signal"] == "wiener deconvolution"
    assert main(["backproject", str(path), "--grid", "1", "--out", str(tmp_path / "x")]) == 2
    assert "--grid" in capsys.readouterr().err


def test_baseband_survey_focuses_like_passband():
    from shsas_core.signal.chain import analytic_signal

    grid = Grid((-0.04, -0.04, 0.0), (0.04, 0.04, 0.08), (16, 16, 16))
    target = grid.points().reshape(*grid.shape, 3)[4, 11, 8]
    s = _helix_survey(target[None], n=60)
    fc = 18e3  # deliberately not the pulse centre
    meta = s.meta.model_copy(update={"signal_kind": "baseband", "carrier_hz": fc})
    sb = Survey(tx=s.tx, rx=s.rx, samples=baseband(analytic_signal(s.samples), s.t0, s.meta.fs, fc),
                t0=s.t0, meta=meta, pulse=s.pulse)
    vp = backproject_survey(s, grid, config=EAGER)
    vb = backproject_survey(sb, grid, config=EAGER)
    assert np.unravel_index(np.argmax(np.abs(vb.values)), grid.shape) == (4, 11, 8)
    # same image up to the finite-window Hilbert transform and interpolation differences
    assert np.abs(np.abs(vb.values) - np.abs(vp.values)).max() < 0.05 * np.abs(vp.values).max()


def test_survey_beams_mask_voxels_outside_the_cone():
    grid = Grid((-0.04, -0.04, 0.0), (0.04, 0.04, 0.08), (8, 8, 8))
    s = _helix_survey(np.array([[0.0, 0.0, 0.04]]), n=30)
    # every ping points straight up with a 10° cone: the scene (below / beside) is outside
    up = np.tile([[0.0, 0.0, 1.0]], (len(s.tx), 1))
    meta = s.meta.model_copy(update={"tx_beamwidth_deg": 10.0, "rx_beamwidth_deg": 10.0})
    off = Survey(tx=s.tx, rx=s.rx, samples=s.samples, t0=s.t0, meta=meta, pulse=s.pulse,
                 tx_dir=up, rx_dir=up)
    assert Beams.from_survey(off) is not None
    vol = backproject_survey(off, grid, config=EAGER)
    assert np.abs(vol.values).max() == 0
    # pointing at the scene centre with a wide cone keeps the image
    centre = np.array([0.0, 0.0, 0.04])
    on = Survey(tx=s.tx, rx=s.rx, samples=s.samples, t0=s.t0,
                meta=s.meta.model_copy(update={"tx_beamwidth_deg": 60.0, "rx_beamwidth_deg": 60.0}),
                pulse=s.pulse, tx_dir=centre - s.tx, rx_dir=centre - s.rx)
    full = backproject_survey(s, grid, config=EAGER)
    np.testing.assert_allclose(backproject_survey(on, grid, config=EAGER).values, full.values, atol=1e-5 * np.abs(full.values).max())
