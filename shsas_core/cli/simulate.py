"""`shsas simulate`: simulate a bistatic SAS survey of a mesh, with ground truth inside."""

from __future__ import annotations

import argparse

_EPILOG = """examples:
  shsas simulate --shape torus --heights 10 --angles 360 --snr 20 --seed 0 --out torus.h5
  shsas simulate --mesh bunny.obj --heights 150 --angles 360 --out bunny_full.h5
  shsas simulate --shape scene --trajectory helical --heights 20 --angles 90 --every 2 --out s.h5
  shsas simulate --shape cube --trajectory linear --heights 4 --track-pings 300 --specular 2 \\
      --spreading --keep-clean --no-noise --out strip.h5
The model, the surface sampling rule and the SNR definition are in docs/simulation.md."""


#: config fields whose command-line option has another name
_OPTION_NAMES = {"tx_beamwidth_deg": "tx-beamwidth", "rx_beamwidth_deg": "rx-beamwidth",
                 "specular_weight": "specular", "snr_db": "snr", "kind": "trajectory"}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate", help="simulate a SAS survey of a mesh or built-in shape (with ground truth)",
        description="Simulate a bistatic SAS survey: the mesh is sampled into surface points "
        "(spacing below a quarter of the shortest wavelength), each point echoes the LFM pulse "
        "with its exact (fractional) delay when it faces and sees both the transmitter and the "
        "receiver, with a Lambertian term plus an optional directional lobe; white noise is added "
        "at the requested in-band SNR. The output is a canonical survey file holding the mesh "
        "as ground truth. Same options and seed give the same file, byte for byte.",
        epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--mesh", metavar="PATH", help="mesh file (OBJ/PLY/STL/GLB) in metres, z up")
    src.add_argument("--shape", metavar="NAME", help="built-in shape: sphere, cube, torus, scene, plate, pipe, bowl or shadow")
    src.add_argument("--points", metavar="FILE.npy",
                     help="point scatterers instead of a mesh: (M, 3) positions or (M, 6) positions "
                     "and normals, metres (no occlusion, no ground truth mesh)")
    p.add_argument("--out", required=True, metavar="FILE.h5", help="survey file to write")

    g = p.add_argument_group("trajectory")
    g.add_argument("--trajectory", choices=["circular", "helical", "linear"], default="circular",
                   help="circular (AirSAS turntable, default), helical or linear side-looking passes")
    g.add_argument("--heights", type=int, default=10, help="circles / helix turns / linear passes (default 10)")
    g.add_argument("--angles", type=int, default=360, help="pings per turn, circular/helical (default 360)")
    g.add_argument("--height-min", type=float, default=0.11, help="lowest TX height, m (default 0.11)")
    g.add_argument("--height-max", type=float, default=0.86, help="highest TX height, m (default 0.86)")
    g.add_argument("--height-step", type=float, default=None,
                   help="TX height step, m (e.g. 0.005 as AirSAS); overrides --height-max")
    g.add_argument("--tx-radius", type=float, default=0.85, help="TX circle radius, m (default 0.85)")
    g.add_argument("--track-length", type=float, default=1.0, help="linear pass length, m (default 1)")
    g.add_argument("--track-pings", type=int, default=200, help="pings per linear pass (default 200)")
    g.add_argument("--standoff", type=float, default=0.85, help="linear pass distance to the centre, m")
    g.add_argument("--every", type=int, default=1, help="keep every k-th ping (sparse survey)")
    g.add_argument("--fraction", type=float, default=1.0, help="keep a random fraction of pings (0-1]")
    g.add_argument("--subset-seed", type=int, default=0, help="seed of the random ping subset")

    g = p.add_argument_group("pulse and sampling")
    g.add_argument("--f-start", type=float, default=10e3, help="chirp start frequency, Hz (default 10e3)")
    g.add_argument("--f-stop", type=float, default=30e3, help="chirp stop frequency, Hz (default 30e3)")
    g.add_argument("--duration", type=float, default=1e-3, help="pulse length, s (default 1e-3)")
    g.add_argument("--window", choices=["tukey", "hann", "taylor", "rect"], default="tukey")
    g.add_argument("--window-param", type=float, default=0.1, help="Tukey ratio (default 0.1)")
    g.add_argument("--fs", type=float, default=100e3, help="sample rate, Hz (default 100e3)")
    g.add_argument("--sound-speed", type=float, default=343.0, help="m/s (default 343)")

    g = p.add_argument_group("scattering and noise")
    g.add_argument("--snr", type=float, default=20.0, metavar="DB", help="in-band SNR, dB (default 20)")
    g.add_argument("--no-noise", action="store_true", help="add no noise (ignore --snr)")
    g.add_argument("--seed", type=int, default=0, help="seed of sampling, random terms and noise")
    g.add_argument("--lambert", choices=["tx", "rx", "both", "none"], default="tx",
                   help="Lambertian cosine toward the TX (default), RX, both (geometric mean) or none")
    g.add_argument("--specular", type=float, default=0.0, metavar="W",
                   help="directional lobe peak relative to the Lambertian peak (default 0: off)")
    g.add_argument("--specular-exponent", type=float, default=20.0, help="lobe sharpness (default 20)")
    g.add_argument("--spreading", action="store_true", help="two-way spherical spreading loss")
    g.add_argument("--random-phase", action="store_true", help="random phase per point (speckle)")
    g.add_argument("--random-amplitude", action="store_true", help="Rayleigh amplitude per point")
    g.add_argument("--tx-beamwidth", type=float, default=None, metavar="DEG",
                   help="full TX cone angle, degrees (default: omnidirectional); beams point at "
                   "the scene centre, broadside on linear passes")
    g.add_argument("--rx-beamwidth", type=float, default=None, metavar="DEG",
                   help="full RX cone angle, degrees (default: omnidirectional)")
    g.add_argument("--two-sided", action="store_true", help="surfaces scatter from both sides")
    g.add_argument("--no-occlusion", action="store_true", help="skip shadow rays (faster, wrong)")
    g.add_argument("--spacing-fraction", type=float, default=0.25,
                   help="surface point spacing as a fraction of the shortest wavelength (default 0.25)")
    g.add_argument("--keep-clean", action="store_true", help="also store the noise-free signal")
    g.add_argument("--scene-box", type=float, nargs=6, default=None,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="scene box stored in the survey and used for the record window, m "
                   "(default: the mesh bounds plus 2 cm)")
    g.add_argument("--compression", choices=["none", "gzip", "lzf"], default="none",
                   help="compression of the sample arrays (default none)")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)

    def one_line_error(message: str) -> None:
        # argparse would print the whole usage block first; one line says it all here
        p.exit(2, f"shsas simulate: error: {message} (see shsas simulate --help)\n")

    p.error = one_line_error  # type: ignore[method-assign]


def build_config(args: argparse.Namespace):
    """SimulationConfig from the parsed options; invalid values raise ShsasError."""
    import pydantic

    from shsas_core.common.errors import ShsasError
    from shsas_core.data.survey import PulseParams, SceneBox
    from shsas_core.simulation.simulate import ScatteringConfig, SimulationConfig, TrajectoryConfig

    try:
        traj = TrajectoryConfig(
            kind=args.trajectory, heights=args.heights, angles=args.angles,
            height_min=args.height_min, height_max=args.height_max, height_step=args.height_step,
            tx_radius=args.tx_radius, track_length=args.track_length, track_pings=args.track_pings,
            standoff=args.standoff, every=args.every, fraction=args.fraction,
            subset_seed=args.subset_seed)
        pulse = PulseParams(f_start=args.f_start, f_stop=args.f_stop, duration=args.duration,
                            window=args.window, window_param=args.window_param)
        scat = ScatteringConfig(
            lambert=args.lambert, specular_weight=args.specular,
            specular_exponent=args.specular_exponent, spreading=args.spreading,
            random_phase=args.random_phase, random_amplitude=args.random_amplitude,
            two_sided=args.two_sided, occlusion=not args.no_occlusion,
            spacing_fraction=args.spacing_fraction, tx_beamwidth_deg=args.tx_beamwidth,
            rx_beamwidth_deg=args.rx_beamwidth)
        box = None
        if args.scene_box is not None:
            try:
                box = SceneBox(min=tuple(args.scene_box[:3]), max=tuple(args.scene_box[3:]))
            except pydantic.ValidationError as exc:
                msg = exc.errors()[0]["msg"].removeprefix("Value error, ")
                raise ShsasError(f"--scene-box: {msg}") from None
        return SimulationConfig(
            trajectory=traj, pulse=pulse, scattering=scat, fs=args.fs,
            sound_speed=args.sound_speed, snr_db=None if args.no_noise else args.snr,
            seed=args.seed, keep_clean=args.keep_clean, scene_box=box)
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        msg = err["msg"].removeprefix("Value error, ")
        if not err["loc"]:  # a check across several options
            raise ShsasError(f"invalid options: {msg}"[:300]) from None
        name = str(err["loc"][-1])
        loc = "--" + _OPTION_NAMES.get(name, name).replace("_", "-")
        raise ShsasError(f"{loc}: {msg} (got {err.get('input')!r})"[:300]) from None


def load_points(path: str):
    """Scatterers from a .npy file holding (M, 3) positions or (M, 6) positions + normals."""
    import numpy as np

    from shsas_core.common.errors import ShsasError
    from shsas_core.simulation.scatterers import Scatterers

    try:
        a = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise ShsasError(f"points file '{path}' not found") from None
    except (OSError, ValueError) as exc:
        raise ShsasError(f"cannot read points file '{path}': {exc}"[:300]) from None
    if a.ndim != 2 or a.shape[1] not in (3, 6) or len(a) == 0 or not np.issubdtype(a.dtype, np.number):
        raise ShsasError(f"points file '{path}' must hold a numeric (M, 3) or (M, 6) array, got {a.shape}")
    return Scatterers(points=a[:, :3], normals=a[:, 3:] if a.shape[1] == 6 else None)


def run(args: argparse.Namespace) -> int:
    from shsas_core.common.progress import TqdmProgress
    from shsas_core.formats.hdf5 import write_survey
    from shsas_core.simulation.shapes import load_mesh
    from shsas_core.simulation.simulate import simulate

    cfg = build_config(args)
    if args.points is not None:
        mesh, points = None, load_points(args.points)
    else:
        mesh, points = load_mesh(args.mesh if args.mesh is not None else args.shape), None
    bar = TqdmProgress(disable=args.quiet)
    try:
        survey = simulate(mesh, cfg, scatterers=points, progress=bar)
    finally:
        bar.close()
    path = write_survey(survey, args.out, compression=None if args.compression == "none" else args.compression)
    a = survey.meta.attrs
    print(f"wrote {path}: {survey.num_pings} pings x {survey.num_samples} samples, "
          f"{a['num_scatterers']} surface points, {a['visible_contributions']} echoes")
    return 0
