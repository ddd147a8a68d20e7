"""Builders of small synthetic files in the layouts the importers accept (docs/formats.md).

The AirSAS builder writes what the acquisition software writes (header row in Coordinates.csv,
``name,value`` SysParams rows, ``NAME_<f>Hz_<f>Hz_<d>s_x_y_<tukey>`` waveform strings); the SVSS
builder writes the unpack / motion-solution HDF5 pair and a track XML.
"""

from __future__ import annotations

import pickle
import sys
import types
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np
from scipy.signal import windows

FS = 100e3
GD = 12.4  # group delay, samples (fractional on purpose)


def lfm(f0: float, f1: float, dur: float, fs: float, tukey: float) -> np.ndarray:
    """Independent LFM reference (not shsas_core.data.pulse): cos(2π(f0 t + ½ k t²)) · tukey."""
    n = round(dur * fs)
    t = np.arange(n) / fs
    return np.cos(2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / dur * t * t)) * windows.tukey(n, tukey)


@dataclass
class AirSASScan:
    """Parameters of a synthetic AirSAS scan; ``write`` puts it in a folder."""

    angles: list[float] = field(default_factory=lambda: [0.0, 90.0, 180.0, 270.0])
    heights_mm: list[float] = field(default_factory=lambda: [0.0, 0.0, 5.0, 5.0])
    temps_c: list[float] = field(default_factory=lambda: [20.0, 21.0, 22.0, 23.0])
    waveform: list[int] | None = None
    speaker: tuple[float, float, float] = (0.85, 0.0, 0.30)
    mic: tuple[float, float, float] = (0.863, 0.0, 0.262)
    center: tuple[float, float, float] = (0.01, -0.02, 0.05)
    gd: float = GD
    fs: float = FS
    n_samples: int = 1200
    target: tuple[float, float, float] = (0.02, -0.01, 0.08)
    amplitude: float = 1.0
    header: bool = True

    @property
    def pulse(self) -> np.ndarray:
        return lfm(10e3, 30e3, 1e-3, self.fs, 0.1)

    def positions(self) -> tuple[np.ndarray, np.ndarray]:
        """Hand-written geometry: Rz(angle)·p − center + (0, 0, h/1000), one ping at a time."""
        tx, rx = [], []
        for a, h in zip(self.angles, self.heights_mm, strict=True):
            ca, sa = np.cos(np.radians(a)), np.sin(np.radians(a))
            for p, out in ((self.speaker, tx), (self.mic, rx)):
                out.append([ca * p[0] - sa * p[1] - self.center[0],
                            sa * p[0] + ca * p[1] - self.center[1],
                            p[2] - self.center[2] + h / 1000.0])
        return np.array(tx), np.array(rx)

    def echo_delays(self) -> np.ndarray:
        """Two-way delay (s after transmit) of the point target for each ping."""
        tx, rx = self.positions()
        c = 331.4 + 0.6 * np.mean(self.temps_c)
        x = np.asarray(self.target)
        return (np.linalg.norm(tx - x, axis=1) + np.linalg.norm(rx - x, axis=1)) / c

    def raw(self) -> np.ndarray:
        """(N, T) raw recordings: the pulse placed at delay + group delay (nearest sample)."""
        out = np.zeros((len(self.angles), self.n_samples))
        for i, tau in enumerate(self.echo_delays()):
            k = round(tau * self.fs + self.gd)
            out[i, k:k + self.pulse.size] = self.amplitude * self.pulse
        return out

    def write(self, folder: Path, data: np.ndarray | None = None) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        data = self.raw() if data is None else data
        wf = self.waveform or [0] * len(self.angles)
        lines = ["Flight,Angle,Height,Temperature,Waveform"] if self.header else []
        for i, (a, h, t, w) in enumerate(zip(self.angles, self.heights_mm, self.temps_c, wf, strict=True)):
            lines.append(f"{i + 1},{a},{h},{t},{w}")
        (folder / "Coordinates.csv").write_text("\n".join(lines) + "\n")
        sp = [("Speaker", self.speaker), ("Mic1", self.mic), ("Center", self.center)]
        rows = [f"{name} {ax},{v!r}" for name, p in sp for ax, v in zip("xyz", p, strict=True)]
        rows += [f"Group Delay,{self.gd!r}", f"Fs,{self.fs!r}", "Operator,someone"]
        (folder / "SysParams.csv").write_text("\n".join(rows) + "\n")
        (folder / "WaveformParams.csv").write_text(
            "LFM_1.000E+4Hz_3.000E+4Hz_1.000E-3s_1.000E+0_1.000E+0_1.000E-1\n"
            "LFM_1.750E+4Hz_2.250E+4Hz_1.000E-3s_1.000E+0_1.000E+0_1.000E-1\n")
        p2 = lfm(17.5e3, 22.5e3, 1e-3, self.fs, 0.1)
        (folder / "Waveforms.csv").write_text(
            "\n".join(f"{float(a)!r},{float(b)!r}" for a, b in zip(self.pulse, p2, strict=True)) + "\n")
        for i, row in enumerate(data):
            (folder / f"Flight-{i + 1:06d}.csv").write_text("\n".join(repr(float(v)) for v in row) + "\n")
        return folder


# ---------------------------------------------------------------------------------------------
# SVSS


@dataclass
class SVSSTrack:
    """A tiny SVSS track: 2 TX, 3 RX elements, 4 firings, 256 samples."""

    name: str = "2019 1106 163841"
    number: int = 7
    tx_body: np.ndarray = field(default_factory=lambda: np.array([[0.0, 0.0, 0.0], [0.1, 0.05, 0.0]]))
    rx_body: np.ndarray = field(default_factory=lambda: np.array([[0.0, -0.1, 0.02], [0.0, 0.0, 0.02],
                                                                  [0.0, 0.1, 0.02]]))
    position: np.ndarray = field(default_factory=lambda: np.array(
        [[0.0, 1.0, 0.5], [0.1, 1.0, 0.5], [0.2, 1.01, 0.51], [0.3, 1.0, 0.5]]))
    roll: np.ndarray = field(default_factory=lambda: np.zeros(4))
    pitch: np.ndarray = field(default_factory=lambda: np.zeros(4))
    yaw: np.ndarray = field(default_factory=lambda: np.array([0.0, np.pi / 2, 0.0, 0.0]))
    n_samples: int = 256
    temperature_f: float | None = 60.0
    kernel: bool = True

    @property
    def rows(self) -> int:
        return len(self.position) * len(self.rx_body)

    def data(self) -> tuple[np.ndarray, np.ndarray]:
        j = np.arange(self.rows)[:, None]
        k = np.arange(self.n_samples)[None, :]
        return (j + 0.001 * k).astype(np.float32), (-j - 0.002 * k).astype(np.float32)

    def write(self, root: Path) -> Path:
        folder = root / self.name
        folder.mkdir(parents=True, exist_ok=True)
        re_, im = self.data()
        with h5py.File(folder / f"unpack float - LF - down - {self.number}.hdf5", "w") as f:
            f["DataReal"], f["DataImag"] = re_, im
        with h5py.File(folder / f"motion solution - LF - down - {self.number}.hdf5", "w") as f:
            f["Position"] = self.position
            f["Attitude/Roll"], f["Attitude/Pitch"], f["Attitude/Yaw"] = self.roll, self.pitch, self.yaw

        def block(tag: str, pos: np.ndarray) -> str:
            els = "".join(f"<element><x>{float(p[0])!r}</x><y>{float(p[1])!r}</y><z>{float(p[2])!r}</z></element>" for p in pos)
            return f"<{tag}>{els}</{tag}>"

        kern = ""
        if self.kernel:
            kern = ("<kernel><real>9</real><imag>9</imag></kernel>"
                    "<kernel><real>1.0</real><imag>0.0</imag><real>0.5</real><imag>-0.5</imag>"
                    "<real>0.25</real><imag>0.25</imag></kernel>")
        (folder / f"{self.name}.xml").write_text(
            f"<?xml version='1.0'?><sonar><array>{block('tx', self.tx_body)}{block('rx', self.rx_body)}"
            f"</array>{kern}</sonar>")
        if self.temperature_f is not None:
            (folder / "sound_speed.csv").write_text(f"track,temperature_f\nother,40\n{self.name},{self.temperature_f}\n")
        return folder


# ---------------------------------------------------------------------------------------------
# processed AirSAS pickle, written with stand-ins of the reference code's record classes


def _schema_module() -> types.ModuleType:
    mod = types.ModuleType("data_schemas")

    class _Rec:
        def __init__(self) -> None:
            self._data: dict = {}

        def __setitem__(self, k, v):
            self._data[k] = v

    for name in ("SASDataSchema", "SysParams", "WfmParams", "WfmCropSettings", "Geometry"):
        cls = type(name, (_Rec,), {"__module__": "data_schemas"})
        cls.__qualname__ = name
        setattr(mod, name, cls)
    return mod


def write_airsas_pickle(path: Path, scan: AirSASScan, protocol: int = 4) -> dict:
    """Pickle a reference-code-like ``system_data.pik`` for ``scan``; return the values used."""
    mod = _schema_module()
    sys.modules["data_schemas"] = mod
    try:
        tx, rx = scan.positions()
        data = scan.raw()[:, 12:]  # "group-delay corrected" the way the reference code leaves it
        sp, wp, geo, crop, root = mod.SysParams(), mod.WfmParams(), mod.Geometry(), mod.WfmCropSettings(), \
            mod.SASDataSchema()
        sp["sampling_frequency"], sp["group_delay"], sp["center_frequency"] = scan.fs, scan.gd, 20e3
        sp["tx_pos"], sp["rx_pos"], sp["center"] = np.array(scan.speaker), np.array(scan.mic), np.array(scan.center)
        wp["f_start"], wp["f_stop"], wp["t_dur"], wp["win_ratio"] = 10000, 30000, 1e-3, 0.1
        corners = np.array([[x, y, z] for x in (-0.2, 0.2) for y in (-0.2, 0.2) for z in (0.0, 0.3)])
        geo["corners"], geo["num_x"] = corners, 100
        crop["min_sample"], crop["num_samples"] = 40, 500
        values = {"wfm_data": data, "tx_coords": tx, "rx_coords": rx, "temps": np.array(scan.temps_c),
                  "speed_of_sound": 331.4 + 0.6 * float(np.mean(scan.temps_c)), "wfm": scan.pulse,
                  "sys_params": sp, "wfm_params": wp, "geometry": geo, "crop_settings": crop,
                  "wfm_rc": data.astype(np.complex128), "same_tx_per_k_rx": None}
        for k, v in values.items():
            root[k] = v
        path.write_bytes(pickle.dumps(root, protocol=protocol))
        return values
    finally:
        del sys.modules["data_schemas"]
