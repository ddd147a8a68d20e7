"""Sensor trajectories for simulated surveys: TX and RX positions per ping.

Kinds (all in metres, scene frame, z up):

- ``circular``: AirSAS-like. The object turns on a turntable, which is the same as the sensors
  circling it: ``angles`` pings per turn at each of ``heights`` heights (ping order: all angles
  of the lowest height, then the next height up). TX on a circle of radius ``tx_radius``
  (0.85 m); the RX sits ``rx_radial_offset`` (13 mm) further out and ``rx_vertical_offset``
  (38 mm) lower, as in the paper's simulated surveys (TX heights 0.11-0.86 m).
- ``helical``: the same circles, but the height rises continuously, one ``heights`` step per
  turn, so every ping has its own height.
- ``linear``: side-looking strip: ``heights`` straight passes along x of length
  ``track_length`` with ``track_pings`` pings each, at ``standoff`` metres from the centre on
  the -y side, looking +y; the RX is offset ``rx_radial_offset`` further away and
  ``rx_vertical_offset`` lower.
- ``explicit``: the ``tx`` and ``rx`` arrays given.

A sparse subset can then be kept: every ``every``-th ping and/or a random ``fraction``
(seeded by ``subset_seed``); :func:`make_trajectory` returns the kept indices too.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from shsas_core.common.errors import ShsasError


class TrajectoryConfig(BaseModel):
    """Where the transmitter and receiver are for each ping (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True, arbitrary_types_allowed=True)

    kind: Literal["circular", "helical", "linear", "explicit"] = "circular"
    angles: int = Field(360, ge=1, le=100_000, description="pings per turn (circular/helical)")
    heights: int = Field(10, ge=1, le=10_000, description="heights (circular), turns (helical) or passes (linear)")
    height_min: float = Field(0.11, description="lowest TX height, m")
    height_max: float = Field(0.86, description="highest TX height, m (ignored when height_step is set)")
    height_step: float | None = Field(None, gt=0, description="TX height step, m; overrides height_max")
    tx_radius: float = Field(0.85, gt=0, description="TX circle radius, m")
    rx_radial_offset: float = Field(0.013, description="RX distance beyond the TX, away from the centre, m")
    rx_vertical_offset: float = Field(-0.038, description="RX height minus TX height, m")
    angle_start_deg: float = Field(0.0, description="azimuth of the first ping, degrees")
    center: tuple[float, float, float] = Field((0.0, 0.0, 0.0), description="circle centre / strip centre, m")
    track_length: float = Field(1.0, gt=0, description="linear pass length along x, m")
    track_pings: int = Field(200, ge=1, le=1_000_000, description="pings per linear pass")
    standoff: float = Field(0.85, gt=0, description="linear pass distance from the centre (on -y), m")
    every: int = Field(1, ge=1, description="keep every k-th ping")
    fraction: float = Field(1.0, gt=0, le=1, description="then keep this random fraction of pings")
    subset_seed: int = Field(0, ge=0, description="seed of the random subset")
    tx: Any = Field(None, description="explicit (N, 3) TX positions, m")
    rx: Any = Field(None, description="explicit (N, 3) RX positions, m")

    @field_validator("tx", "rx", mode="before")
    @classmethod
    def _array(cls, v: Any) -> np.ndarray | None:
        if v is None:
            return None
        a = np.asarray(v, dtype=np.float64)
        if a.ndim == 1 and a.shape[0] == 3:
            a = a[None]
        if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
            raise ValueError(f"must have shape (N, 3), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("contains NaN or inf")
        return a

    @model_validator(mode="after")
    def _consistent(self) -> TrajectoryConfig:
        if self.kind == "explicit":
            if self.tx is None or self.rx is None:
                raise ValueError("kind='explicit' needs both tx and rx arrays")
            if self.tx.shape != self.rx.shape:
                raise ValueError(f"tx {self.tx.shape} and rx {self.rx.shape} must have the same shape")
        elif self.tx is not None or self.rx is not None:
            raise ValueError(f"tx/rx arrays are only used with kind='explicit' (kind is '{self.kind}')")
        if self.height_step is None and self.heights > 1 and self.height_max < self.height_min:
            raise ValueError(f"height_max {self.height_max} is below height_min {self.height_min}")
        return self

    def describe(self) -> dict[str, Any]:
        """JSON-friendly settings (explicit arrays summarised by their shape)."""
        d = self.model_dump(exclude={"tx", "rx"})
        if self.tx is not None:
            d["explicit_pings"] = len(self.tx)
        return d

    def tx_heights(self) -> np.ndarray:
        """(H,) TX heights of the circles or passes, m."""
        k = np.arange(self.heights)
        if self.height_step is not None:
            return self.height_min + self.height_step * k
        if self.heights == 1:
            return np.array([self.height_min])
        return np.linspace(self.height_min, self.height_max, self.heights)


def _ring(radius: np.ndarray, az: np.ndarray, z: np.ndarray, center: np.ndarray) -> np.ndarray:
    return np.stack([radius * np.cos(az), radius * np.sin(az), z], axis=1) + center


def full_trajectory(cfg: TrajectoryConfig) -> tuple[np.ndarray, np.ndarray]:
    """All pings before any subset: ``(tx, rx)``, each (N, 3) float64, m."""
    c = np.asarray(cfg.center, dtype=np.float64)
    if cfg.kind == "explicit":
        return cfg.tx.copy(), cfg.rx.copy()
    z = cfg.tx_heights()
    if cfg.kind in ("circular", "helical"):
        a = cfg.angles
        k = np.arange(cfg.heights * a)
        az = np.radians(cfg.angle_start_deg) + 2 * np.pi * (k % a) / a
        if cfg.kind == "circular":
            zt = np.repeat(z, a)
        else:
            step = (z[1] - z[0]) if len(z) > 1 else 0.0
            zt = z[0] + step * k / a  # rises one height step per turn
        r_tx = np.full(len(k), cfg.tx_radius)
        tx = _ring(r_tx, az, zt, c)
        rx = _ring(r_tx + cfg.rx_radial_offset, az, zt + cfg.rx_vertical_offset, c)
        return tx, rx
    # linear: passes along x on the -y side, looking +y
    xs = np.linspace(-cfg.track_length / 2, cfg.track_length / 2, cfg.track_pings)
    x = np.tile(xs, cfg.heights)
    zt = np.repeat(z, cfg.track_pings)
    tx = np.stack([x, np.full_like(x, -cfg.standoff), zt], axis=1) + c
    rx = np.stack([x, np.full_like(x, -cfg.standoff - cfg.rx_radial_offset),
                   zt + cfg.rx_vertical_offset], axis=1) + c
    return tx, rx


def subset_indices(n: int, every: int = 1, fraction: float = 1.0, seed: int = 0) -> np.ndarray:
    """Indices (sorted, int64) of the pings kept: every ``every``-th, then a random
    ``fraction`` of those (at least one), drawn with ``numpy.random.default_rng(seed)``."""
    idx = np.arange(0, n, every, dtype=np.int64)
    if fraction < 1.0:
        keep = max(1, round(fraction * len(idx)))
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(idx, size=keep, replace=False))
    return idx


def make_trajectory(cfg: TrajectoryConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """TX and RX positions of the kept pings.

    Returns:
        ``(tx, rx, index)``: (N, 3) float64 m each, and (N,) int64 index of each kept ping in
        the full trajectory.
    """
    tx, rx = full_trajectory(cfg)
    idx = subset_indices(len(tx), cfg.every, cfg.fraction, cfg.subset_seed)
    if len(idx) == 0:
        raise ShsasError("the ping subset is empty")
    return tx[idx], rx[idx], idx


def azimuth_deg(positions: np.ndarray, center: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Azimuth of each position about the vertical axis through ``center``, degrees in [0, 360).

    Measured counter-clockwise from +x (the circular trajectory's convention: its first ping
    at ``angle_start_deg = 0`` lies on +x). Rounded to 1e-9 degrees first, so that a ping
    meant to lie on a whole angle (0°, 180°) is not moved across it by sine/cosine round-off
    (``0.85·sin(π)`` is 1e-16, not 0). A position on the axis has azimuth 0.

    Args:
        positions: (N, 3) or (N, 2) positions, m (only x and y are used).
        center: (x, y) of the axis, m.
    """
    p = np.asarray(positions, dtype=np.float64)
    az = np.degrees(np.arctan2(p[:, 1] - center[1], p[:, 0] - center[0]))
    return np.mod(np.round(az, 9), 360.0)


def azimuth_arc_indices(positions: np.ndarray, start_deg: float, stop_deg: float,
                        center: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Indices (sorted, int64) of the positions whose azimuth lies in the arc [start, stop).

    A limited-aperture survey keeps only the pings whose transmitter is on part of the circle,
    e.g. ``survey.subset(azimuth_arc_indices(survey.tx, 0, 180))`` keeps a half turn of the
    turntable. The arc is half-open and runs counter-clockwise from ``start_deg``; it may wrap
    through 0° by giving ``stop_deg`` above 360 (``[270, 450)`` is the half circle through +x).

    Args:
        positions: (N, 3) or (N, 2) positions, m.
        start_deg, stop_deg: arc ends, degrees (see :func:`azimuth_deg` for the convention);
            ``0 < stop_deg - start_deg <= 360``.
        center: (x, y) of the vertical axis, m.

    Raises:
        ValueError: for an empty or over-full arc.
    """
    width = float(stop_deg) - float(start_deg)
    if not 0.0 < width <= 360.0:
        raise ValueError(f"arc [{start_deg}, {stop_deg}) must span more than 0 and at most 360 degrees")
    n = len(np.asarray(positions))
    if width == 360.0:  # np.mod of a tiny negative offset rounds to 360.0, which `<` would drop
        return np.arange(n, dtype=np.int64)
    offset = np.mod(azimuth_deg(positions, center) - float(start_deg), 360.0)
    return np.flatnonzero(offset < width).astype(np.int64)
