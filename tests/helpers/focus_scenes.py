"""Small simulated surveys of point scatterers for the focus tests (the project's simulator).

Few pings, few points and no noise keep each survey cheap; their geometry is exact, so any
error a test puts in is the only one there.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from shsas_core.data.survey import PulseParams, SceneBox, Survey
from shsas_core.simulation.scatterers import Scatterers
from shsas_core.simulation.simulate import SimulationConfig, simulate
from shsas_core.simulation.trajectory import TrajectoryConfig

#: Points in the plane z = PLANE_Z, spread so the image has structure in x and y.
PLANE_Z = 0.02
PLANE_POINTS = np.array([[0.0, 0.0], [0.04, 0.01], [-0.03, 0.035], [0.015, -0.045], [-0.045, -0.02]])
BOX = SceneBox(min=(-0.08, -0.08, -0.04), max=(0.08, 0.08, 0.08))


#: The narrowband scans' band: 5 kHz around 20 kHz (34 mm range resolution in air).
NARROW_BAND_HZ = (17.5e3, 22.5e3)


def plane_scene(angles: int = 120, *, box: SceneBox = BOX, band_hz: tuple[float, float] | None = None,
                snr_db: float | None = None, axis_echo: tuple[float, float] | None = None) -> Survey:
    """One height level (TX at 0.25 m), five points in the plane z = PLANE_Z.

    Args:
        box: the survey's scene box (the points need not lie in it).
        band_hz: (low, high) of the LFM pulse (default the simulator's 10-30 kHz).
        snr_db: in-band noise (None: none).
        axis_echo: (height, amplitude) of one more point on the rotation axis: its echo comes
            at the same delay in every ping, like a turntable scan's room echo.
    """
    pts = np.column_stack([PLANE_POINTS, np.full(len(PLANE_POINTS), PLANE_Z)])
    amp = np.ones(len(pts))
    if axis_echo is not None:
        pts = np.vstack([pts, [0.0, 0.0, axis_echo[0]]])
        amp = np.append(amp, axis_echo[1])
    extra = {} if band_hz is None else {"pulse": PulseParams(f_start=band_hz[0], f_stop=band_hz[1])}
    cfg = SimulationConfig(trajectory=TrajectoryConfig(angles=angles, heights=1, height_min=0.25),
                           snr_db=snr_db, scene_box=box, **extra)
    return simulate(None, cfg, scatterers=Scatterers(pts, amplitude=amp))


def levels_scene(angles: int = 60, levels: int = 3) -> Survey:
    """``levels`` height levels 0.1 m apart from 0.15 m; points spread in 3-D."""
    pts = np.array([[0.0, 0.0, 0.0], [0.04, 0.01, 0.03], [-0.03, 0.035, 0.05], [0.015, -0.045, 0.01],
                    [-0.045, -0.02, 0.04]])
    traj = TrajectoryConfig(angles=angles, heights=levels, height_min=0.15, height_step=0.1)
    cfg = SimulationConfig(trajectory=traj, snr_db=None, scene_box=BOX)
    return simulate(None, cfg, scatterers=Scatterers(pts))


def perturbed(survey: Survey, *, sound_speed_rel: float = 0.0, range_offset_m: float = 0.0,
              level_dz: np.ndarray | None = None, radius_m: float = 0.0) -> Survey:
    """The same data described with wrong parameters: the survey says ``c (1 + rel)``, its
    first samples ``2 dr / c`` later than they were taken (a negative ``dr`` drops the leading
    samples that would come before transmit), level k's sensors ``dz[k]`` too high and every
    sensor ``radius_m`` further from the z axis. Autofocus should find ``rel``, ``dr``,
    ``-(dz - dz[0])`` and ``-radius_m``."""
    c, fs = survey.meta.sound_speed, survey.meta.fs
    tx, rx = survey.tx.copy(), survey.rx.copy()
    if level_dz is not None:
        from shsas_core.data.geometry import height_levels

        dz = np.asarray(level_dz)[height_levels(survey.tx).index]
        tx[:, 2] += dz
        rx[:, 2] += dz
    for p in (tx, rx):
        r = np.hypot(p[:, 0], p[:, 1])
        p[:, :2] *= ((r + radius_m) / r)[:, None]
    t0 = survey.t0 + 2 * range_offset_m / c
    drop = max(0, int(np.ceil(-t0.min() * fs - 1e-9)))
    samples = survey.samples[:, drop:]
    return dataclasses.replace(survey, tx=tx, rx=rx, t0=t0 + drop / fs, samples=samples, extras={},
                               shape=samples.shape,
                               meta=survey.meta.model_copy(update={"sound_speed": c * (1 + sound_speed_rel)}))
