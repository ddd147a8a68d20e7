"""The in-memory survey: N pings of bistatic time series plus the metadata needed to image them.

Units throughout: metres, seconds, Hz, scene frame with z up. See docs/formats.md for the file
layout and docs/architecture.md for where the survey flows next.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any, Literal

import numpy as np
import pydantic
from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from shsas_core.common.errors import SurveyValidationError, pydantic_fix

SignalKind = Literal["real", "analytic", "baseband"]

#: Hard limits on sizes; they guard memory before anything is read (see io.read_survey).
MAX_PINGS = 5_000_000
MAX_SAMPLES_PER_PING = 1_000_000
MAX_TOTAL_SAMPLES = 4_000_000_000
MAX_PULSE_SAMPLES = 1_000_000
MAX_MESH_ELEMENTS = 20_000_000


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True)


def _rule(problem: str, fix: str) -> PydanticCustomError:
    """A validator's error that carries its fix (read back by :func:`parse_meta`)."""
    # The problem is the template: escape braces so that pydantic does not format them.
    return PydanticCustomError("meta_rule", problem.replace("{", "{{").replace("}", "}}"), {"fix": fix})


class PulseParams(_Strict):
    """LFM pulse parameters (the samples themselves live in ``Survey.pulse``)."""

    f_start: float = Field(20e3 - 10e3, gt=0, description="start frequency, Hz")
    f_stop: float = Field(20e3 + 10e3, gt=0, description="stop frequency, Hz")
    duration: float = Field(1e-3, gt=0, le=1.0, description="pulse length, s")
    window: Literal["tukey", "hann", "taylor", "rect"] = "tukey"
    window_param: float = Field(0.1, ge=0, description="tukey ratio or taylor sidelobe level (dB)")

    @property
    def f_center(self) -> float:
        return 0.5 * (self.f_start + self.f_stop)

    @property
    def bandwidth(self) -> float:
        return abs(self.f_stop - self.f_start)

    @property
    def f_max(self) -> float:
        return max(self.f_start, self.f_stop)


class SceneBox(_Strict):
    """Axis-aligned box that holds the scene, metres."""

    min: tuple[float, float, float] = (-0.125, -0.125, 0.0)
    max: tuple[float, float, float] = (0.125, 0.125, 0.2)

    @model_validator(mode="after")
    def _ordered(self) -> SceneBox:
        lo, hi = np.asarray(self.min), np.asarray(self.max)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise _rule("corners must be finite", "give min and max as three finite numbers each, metres")
        if np.any(hi <= lo):
            raise _rule(f"max {self.max} must exceed min {self.min} on every axis",
                        "swap the corners, or give the box a non-zero size on every axis")
        return self

    @property
    def size(self) -> np.ndarray:
        return np.asarray(self.max) - np.asarray(self.min)

    @property
    def center(self) -> np.ndarray:
        return 0.5 * (np.asarray(self.max) + np.asarray(self.min))


class SurveyMeta(_Strict):
    """Per-survey scalar metadata, validated by pydantic."""

    fs: float = Field(100e3, gt=0, le=100e6, description="sample rate, Hz")
    sound_speed: float = Field(343.0, ge=300, le=1600, description="sound speed, m/s")
    pulse: PulseParams = PulseParams()
    signal_kind: SignalKind = Field("real", description="real passband, analytic passband or complex baseband")
    carrier_hz: float | None = Field(None, gt=0, description="carrier removed by basebanding (baseband only)")
    tx_beamwidth_deg: float | None = Field(None, gt=0, le=360, description="full TX cone angle, degrees")
    rx_beamwidth_deg: float | None = Field(None, gt=0, le=360, description="full RX cone angle, degrees")
    platform: str = Field("unknown", max_length=64)
    pulse_deconvolved: bool = Field(
        False, description="the samples are already pulse-deconvolved (s_PD, e.g. an external "
        "deconvolution's output): processing takes their analytic signal and never deconvolves again")
    scene_box: SceneBox = SceneBox()
    attrs: dict[str, str | float | int | bool] = Field(default_factory=dict, description="provenance")

    @model_validator(mode="after")
    def _sampling(self) -> SurveyMeta:
        if self.signal_kind == "baseband":
            if self.carrier_hz is None:
                raise _rule("carrier_hz is required when signal_kind is 'baseband'",
                            "set carrier_hz to the frequency removed by basebanding, Hz")
            if self.fs <= self.pulse.bandwidth:
                raise _rule(
                    f"fs={self.fs:g} Hz is not above the pulse bandwidth {self.pulse.bandwidth:g} Hz",
                    "check fs (Hz, not kHz) and pulse.f_start/pulse.f_stop")
        elif self.fs <= 2 * self.pulse.f_max:
            raise _rule(
                f"fs={self.fs:g} Hz is not above twice the top chirp frequency "
                f"({2 * self.pulse.f_max:g} Hz)",
                "check fs and the pulse band (Hz, not kHz); complex baseband data need "
                "signal_kind 'baseband' and carrier_hz")
        return self

    @property
    def range_resolution(self) -> float:
        """``c / 2B``: the two-way range resolution of the pulse band, m."""
        return self.sound_speed / (2 * self.pulse.bandwidth)

    @property
    def resolution_samples(self) -> float:
        """``fs / B``: the samples in one range resolution (one resolution time ``1 / B``), the
        unit the fit's lengths along a ping are given in, so they mean the same at any sample
        rate and band."""
        return self.fs / self.pulse.bandwidth


#: Meta fields that are objects: their fields may also be given flat, as dotted keys
#: (``"pulse.f_start": 20000``), the way docs/formats.md's meta table names them.
NESTED_META = ("pulse", "scene_box", "attrs")


def meta_field_names() -> list[str]:
    """Every meta field as docs/formats.md's table names it: ``fs``, ``pulse.f_start``, ..."""
    names = []
    for name, info in SurveyMeta.model_fields.items():
        sub = info.annotation
        if isinstance(sub, type) and issubclass(sub, BaseModel):
            names += [f"{name}.{k}" for k in sub.model_fields]
        else:
            names.append(name)
    return names


def _unflatten(data: dict[str, Any]) -> dict[str, Any]:
    """Dotted keys of the nested fields into nested objects; both forms may be mixed."""
    out = {k: v for k, v in data.items() if not (isinstance(k, str) and k.split(".", 1)[0] in NESTED_META
                                                  and "." in k)}
    for key, value in data.items():
        if not isinstance(key, str) or "." not in key or key.split(".", 1)[0] not in NESTED_META:
            continue
        head, tail = key.split(".", 1)
        group = out.get(head, {})
        if not isinstance(group, dict):
            raise SurveyValidationError(f"meta.{head}", f"is given both as a value and as the dotted key {key!r}",
                                        f"give {head} either as an object or as dotted keys, not both")
        if tail in group:
            raise SurveyValidationError(f"meta.{key}", "is given twice, as a dotted key and inside the "
                                        f"{head!r} object", "give each field once")
        out[head] = {**group, tail: value}
    return out


def _meta_fix(err: Any) -> str:
    """How to fix one pydantic error of the meta attribute."""
    if err["type"] in ("tuple_type", "list_type", "too_short", "too_long"):
        return "give a list of three numbers (x, y, z), metres"
    if err["type"] == "extra_forbidden":
        return ("remove it or correct the spelling; the meta fields are " + ", ".join(meta_field_names())
                + " (as nested objects or dotted keys, docs/formats.md)")
    return pydantic_fix(err, meta_field_names(), "docs/formats.md, meta table")


def parse_meta(data: dict[str, Any] | str) -> SurveyMeta:
    """Validate metadata from a dict or JSON string; errors name the field ("meta.fs: ...").

    Fields of ``pulse``, ``scene_box`` and ``attrs`` may be nested objects or dotted keys
    (``{"pulse": {"f_start": 1e4}}`` or ``{"pulse.f_start": 1e4}``). Every error names a fix.
    """
    if isinstance(data, str | bytes):
        try:
            data = json.loads(data)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise SurveyValidationError("meta", f"is not valid JSON ({exc})"[:300],
                                        "store meta as a JSON object string, e.g. json.dumps({...})") from None
    if not isinstance(data, dict):
        raise SurveyValidationError("meta", f"must be a JSON object, got {type(data).__name__}",
                                    "store meta as a JSON object string, e.g. json.dumps({...})")
    try:
        return SurveyMeta.model_validate(_unflatten(data))
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        parts = [str(p) for p in err["loc"] if p != "__root__"]
        msg = err["msg"].removeprefix("Value error, ")
        if err["type"] == "missing" and err["loc"] and isinstance(err["loc"][-1], int):
            # A short (x, y, z) list: name the list, not its missing item.
            parts, msg = parts[:-1], "needs three numbers (x, y, z)"
            err = {**err, "type": "too_short"}
        field = "meta" + "".join(f".{p}" for p in parts)
        raise SurveyValidationError(field, f"{msg} (got {err.get('input')!r})"[:400], _meta_fix(err)) from None


#: ``meta.attrs`` entries that count the survey's pings; :meth:`Survey.subset` keeps them true.
PING_COUNT_ATTRS = ("height_levels", "pings_per_level")


def sample_times(t0: np.ndarray, fs: float, num_samples: int) -> np.ndarray:
    """Time of every sample after transmit, ``t0[n] + k / fs``: (N,) s -> (N, T) float64 s.

    The one place the ping time axis is derived: the renderer's range bins, the basebanding
    carrier, the signal shifts and :meth:`Survey.times` all take it from here.
    """
    return np.asarray(t0, dtype=np.float64)[:, None] + np.arange(num_samples)[None, :] / fs


@dataclasses.dataclass
class Survey:
    """A bistatic SAS survey.

    Attributes:
        tx: (N, 3) float64 transmitter positions, m.
        rx: (N, 3) float64 receiver positions, m.
        samples: (N, T) float32 (real) or complex64 (analytic / baseband) time series, or None
            when only the header was read (see ``io.read_survey(load_samples=False)``).
        t0: (N,) float64 time of each ping's first sample after transmit, s.
        meta: scalar metadata (fs, sound speed, pulse parameters, scene box, ...).
        pulse: (P,) float64 (or complex128) transmitted pulse at ``meta.fs``.
        tx_dir, rx_dir: optional (N, 3) unit beam pointing vectors.
        gt_vertices, gt_faces: optional ground-truth mesh, (V, 3) float64 m and (F, 3) int64.
        extras: named per-ping arrays kept with the survey, e.g. ``"deconvolved"`` (N, T)
            complex64 pulse-deconvolved signal, ``"clean"`` noise-free simulation.
    """

    tx: np.ndarray
    rx: np.ndarray
    samples: np.ndarray | None
    t0: np.ndarray
    meta: SurveyMeta
    pulse: np.ndarray
    tx_dir: np.ndarray | None = None
    rx_dir: np.ndarray | None = None
    gt_vertices: np.ndarray | None = None
    gt_faces: np.ndarray | None = None
    extras: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    #: (N, T) shape even when samples were not loaded.
    shape: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        self.tx = np.asarray(self.tx, dtype=np.float64)
        self.rx = np.asarray(self.rx, dtype=np.float64)
        self.t0 = np.asarray(self.t0, dtype=np.float64)
        self.pulse = np.asarray(self.pulse)
        if self.samples is not None:
            self.samples = np.asarray(self.samples)
            if self.samples.dtype == np.float64:
                self.samples = self.samples.astype(np.float32)
            elif self.samples.dtype == np.complex128:
                self.samples = self.samples.astype(np.complex64)
            if self.samples.ndim == 2:
                self.shape = (int(self.samples.shape[0]), int(self.samples.shape[1]))
        for name in ("tx_dir", "rx_dir", "gt_vertices"):
            v = getattr(self, name)
            if v is not None:
                setattr(self, name, np.asarray(v, dtype=np.float64))
        if self.gt_faces is not None:
            self.gt_faces = np.asarray(self.gt_faces, dtype=np.int64)
        self.validate()

    # -- convenience -------------------------------------------------------------------------
    @property
    def num_pings(self) -> int:
        return self.shape[0]

    @property
    def num_samples(self) -> int:
        return self.shape[1]

    @property
    def has_ground_truth(self) -> bool:
        return self.gt_vertices is not None and self.gt_faces is not None

    def times(self, ping: int | None = None) -> np.ndarray:
        """Sample times after transmit, s: (T,) for one ping or (N, T) for all."""
        if ping is not None:
            return sample_times(self.t0[[ping]], self.meta.fs, self.num_samples)[0]
        return sample_times(self.t0, self.meta.fs, self.num_samples)

    def subset(self, index: np.ndarray | slice) -> Survey:
        """A new survey with only the selected pings (extras with a leading N axis follow)."""
        n = self.num_pings

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[index]

        extras = {k: v[index] for k, v in self.extras.items() if v.ndim >= 1 and v.shape[0] == n}
        tx = self.tx[index]
        return dataclasses.replace(
            self, tx=tx, rx=self.rx[index], samples=pick(self.samples),
            t0=self.t0[index], tx_dir=pick(self.tx_dir), rx_dir=pick(self.rx_dir), extras=extras,
            shape=(len(tx), self.num_samples), meta=self._counted_meta(tx),
        )

    def _counted_meta(self, tx: np.ndarray) -> SurveyMeta:
        """``meta`` with the attrs that count pings (:data:`PING_COUNT_ATTRS`) made true for the
        pings at ``tx``: ``pings_per_level`` is removed when the levels no longer hold equally
        many pings."""
        attrs = dict(self.meta.attrs)
        if not any(k in attrs for k in PING_COUNT_ATTRS):
            return self.meta
        from shsas_core.data.geometry import (
            height_levels,  # geometry types its arguments with Survey
        )

        levels = height_levels(tx)
        counts = np.bincount(levels.index, minlength=levels.count)
        if "height_levels" in attrs:
            attrs["height_levels"] = levels.count
        if "pings_per_level" in attrs:
            if counts.size and counts.min() == counts.max():
                attrs["pings_per_level"] = int(counts[0])
            else:
                del attrs["pings_per_level"]
        return self.meta.model_copy(update={"attrs": attrs})

    def ground_truth_mesh(self):
        """The ground truth as a ``trimesh.Trimesh`` (None when absent)."""
        if not self.has_ground_truth:
            return None
        import trimesh

        return trimesh.Trimesh(self.gt_vertices, self.gt_faces, process=False)

    # -- validation --------------------------------------------------------------------------
    def validate(self) -> None:
        """Check shapes, finiteness and physical plausibility; raise SurveyValidationError."""
        n, t = self.shape
        if self.samples is not None:
            if self.samples.ndim != 2:
                raise SurveyValidationError(
                    "pings/samples", f"must be 2-D (pings, samples), got shape {self.samples.shape}",
                    "store one row of samples per ping")
            if not (np.issubdtype(self.samples.dtype, np.floating) or np.iscomplexobj(self.samples)):
                raise SurveyValidationError("pings/samples", f"must be float or complex, got {self.samples.dtype}",
                                            "store float32 (real) or complex64 (analytic/baseband) samples")
        check_sizes(n, t, int(self.pulse.size))
        for name, arr in (("pings/tx", self.tx), ("pings/rx", self.rx)):
            if arr.shape != (n, 3):
                raise SurveyValidationError(name, f"shape {arr.shape} does not match (pings={n}, 3)",
                                            "store one (x, y, z) position per ping, metres")
            if not np.all(np.isfinite(arr)):
                bad = int(np.argwhere(~np.isfinite(arr))[0, 0])
                raise SurveyValidationError(name, f"non-finite position at ping {bad}",
                                            "drop or repair pings with NaN/inf navigation")
        if self.t0.shape != (n,):
            raise SurveyValidationError("pings/t0", f"shape {self.t0.shape} does not match (pings={n},)",
                                        "store one start time per ping, seconds after transmit")
        if not np.all(np.isfinite(self.t0)):
            raise SurveyValidationError("pings/t0", "contains NaN or inf", "drop or repair the bad pings")
        if np.any(self.t0 < 0):
            raise SurveyValidationError("pings/t0", f"negative start time {self.t0.min():g} s",
                                        "t0 is seconds after transmit and must be >= 0")
        if self.pulse.ndim != 1 or not np.all(np.isfinite(self.pulse)):
            raise SurveyValidationError("pulse/samples", "must be a finite 1-D array",
                                        "store the transmitted pulse sampled at meta.fs (docs/formats.md)")
        if not np.any(self.pulse != 0):
            raise SurveyValidationError("pulse/samples", "is all zeros",
                                        "store the transmitted pulse sampled at meta.fs (docs/formats.md)")
        for name in ("tx_dir", "rx_dir"):
            v = getattr(self, name)
            if v is None:
                continue
            if v.shape != (n, 3) or not np.all(np.isfinite(v)):
                raise SurveyValidationError(f"pings/{name}", f"must be finite with shape ({n}, 3), got {v.shape}",
                                            "store one unit vector per ping, or leave the dataset out")
            if np.any(np.linalg.norm(v, axis=1) < 1e-9):
                raise SurveyValidationError(f"pings/{name}", "contains a zero pointing vector",
                                            "store a unit vector for every ping, or leave the dataset out")
        if (self.gt_vertices is None) != (self.gt_faces is None):
            raise SurveyValidationError("ground_truth", "needs both vertices and faces",
                                        "store both datasets, or leave the group out")
        if self.gt_vertices is not None:
            v, f = self.gt_vertices, self.gt_faces
            if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
                raise SurveyValidationError("ground_truth/vertices", f"must be finite (V, 3), got {v.shape}",
                                            "store (x, y, z) per vertex, metres")
            if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
                raise SurveyValidationError("ground_truth/faces", "must be (F, 3) indices into vertices",
                                            "store three 0-based vertex indices per triangle")
        for k, a in self.extras.items():
            if not isinstance(a, np.ndarray):
                raise SurveyValidationError(f"extras/{k}", "must be a numpy array", "store a numeric array")
        if self.samples is not None and not np.all(np.isfinite(self.samples)):
            bad = int(np.argwhere(~np.isfinite(self.samples))[0, 0])
            raise SurveyValidationError("pings/samples", f"non-finite value in ping {bad}",
                                        "drop or repair the bad pings")
        self._check_scene_in_view()

    def _check_scene_in_view(self) -> None:
        """At least one ping's recorded window must reach the scene box."""
        from shsas_core.data.geometry import two_way_range_bounds

        c, fs = self.meta.sound_speed, self.meta.fs
        r_min, r_max = two_way_range_bounds(self.tx, self.rx, self.meta.scene_box)
        w_start = c * self.t0
        w_end = c * (self.t0 + max(self.num_samples - 1, 0) / fs)
        if not np.any((r_max >= w_start) & (r_min <= w_end)):
            raise SurveyValidationError(
                "meta.scene_box",
                f"no ping's recorded range window [{w_start.min():.3f}, {w_end.max():.3f}] m reaches "
                f"the scene box (two-way paths {r_min.min():.3f}..{r_max.max():.3f} m)",
                "check scene_box, t0 and sensor positions (units are metres and seconds)",
            )


def check_sizes(n: int, t: int, p: int) -> None:
    """Size limits checked from declared shapes, before any data is read."""
    if n <= 0:
        raise SurveyValidationError("pings/samples", "survey has no pings", "a survey needs at least one ping")
    if t <= 0:
        raise SurveyValidationError("pings/samples", "pings have no samples", "each ping needs at least one sample")
    if n > MAX_PINGS:
        raise SurveyValidationError("pings/samples", f"{n} pings exceeds the limit of {MAX_PINGS}",
                                    "split the survey into several files")
    if t > MAX_SAMPLES_PER_PING:
        raise SurveyValidationError("pings/samples", f"{t} samples per ping exceeds the limit of {MAX_SAMPLES_PER_PING}",
                                    "crop each ping to the range window of the scene")
    if n * t > MAX_TOTAL_SAMPLES:
        raise SurveyValidationError("pings/samples", f"{n}x{t} samples exceeds the limit of {MAX_TOTAL_SAMPLES}",
                                    "crop the pings to the scene, or split the survey")
    if p <= 0 or p > MAX_PULSE_SAMPLES:
        raise SurveyValidationError("pulse/samples", f"pulse has {p} samples (allowed 1..{MAX_PULSE_SAMPLES})",
                                    "store the transmitted pulse sampled at meta.fs (docs/formats.md)")


#: /pulse/samples and meta.pulse disagree when the samples' length is off duration·fs by more
#: than this factor (the AirSAS importer's tolerance for a recorded waveform) ...
PULSE_LENGTH_FACTOR = 2.0
#: ... or less than this fraction of the pulse's energy lies in meta.pulse's band (widened by
#: max(10 % of the bandwidth, 2/duration) on each side: a short pulse's spectrum is wide), or
#: its mean frequency is off the band centre by more than max(25 % of the bandwidth, 2/duration).
PULSE_MIN_IN_BAND = 0.5

_PULSE_FIX = ("make meta.pulse (f_start, f_stop, duration) describe the pulse stored in /pulse/samples, "
              "sampled at meta.fs; for baseband surveys store it basebanded like the samples "
              "(docs/formats.md, 'The pulse')")


def pulse_disagreement(meta: SurveyMeta, pulse: np.ndarray) -> str | None:
    """How ``/pulse/samples`` and ``meta.pulse`` disagree, as a one-line message; None if they agree.

    Processing correlates with the samples (matched filter, deconvolution replica) but takes
    the band from ``meta.pulse`` (the deconvolution filter's band, the demodulation carrier):
    two descriptions of different pulses give noise, not an image. The checks are loose
    enough for a recorded pulse (an AirSAS waveform, an SVSS kernel); see docs/formats.md.
    """
    pulse = np.asarray(pulse)
    fs, pp = meta.fs, meta.pulse
    expect = max(round(pp.duration * fs), 1)
    n_p = int(pulse.size)
    if not expect / PULSE_LENGTH_FACTOR <= n_p <= expect * PULSE_LENGTH_FACTOR:
        return (f"pulse/samples: has {n_p} samples ({n_p / fs:.4g} s at meta.fs) but meta.pulse.duration x "
                f"meta.fs = {expect} samples: the two pulse descriptions disagree (fix: {_PULSE_FIX})")
    # The spectrum in the frame processing uses: a real pulse is made analytic (positive
    # frequencies) and, for baseband data, shifted down by the carrier; a complex pulse is
    # taken as it is (analytic passband, or already basebanded for baseband data).
    n_fft = 1 << max(int(np.ceil(np.log2(8 * n_p))), 10)
    power = np.abs(np.fft.fft(pulse, n_fft)) ** 2
    freq = np.fft.fftfreq(n_fft, 1.0 / fs)
    lo, hi = min(pp.f_start, pp.f_stop), max(pp.f_start, pp.f_stop)
    carrier = float(meta.carrier_hz or 0.0) if meta.signal_kind == "baseband" else 0.0
    if not np.iscomplexobj(pulse):
        power = np.where(freq > 0, power, 0.0)
        freq = freq - carrier
    lo, hi = lo - carrier, hi - carrier
    margin = max(0.1 * (hi - lo), 2.0 / pp.duration)
    # Sampled frequencies wrap around fs (a basebanded band may straddle ±fs/2).
    inside = np.mod(freq - (lo - margin), fs) <= (hi - lo) + 2 * margin
    total = float(power.sum())
    share = float(power[inside].sum()) / total if total > 0 else 0.0
    # Energy-weighted mean frequency, relative to the band centre (wrapped like the band): a
    # pulse at the wrong rate or band can have half its energy in a wide band and still be
    # centred elsewhere.
    rel = np.mod(freq - 0.5 * (lo + hi) + fs / 2, fs) - fs / 2
    offset = float((power * rel).sum()) / total if total > 0 else float("inf")
    frame = f" after basebanding by carrier_hz={carrier:g}" if carrier else ""
    if share < PULSE_MIN_IN_BAND or abs(offset) > max(0.25 * (hi - lo), 2.0 / pp.duration):
        return (f"pulse/samples: {share:.0%} of its energy lies in the band of meta.pulse ({lo:g}..{hi:g} Hz"
                f"{frame}) and its mean frequency is {0.5 * (lo + hi) + offset:g} Hz: the two pulse "
                f"descriptions disagree (fix: {_PULSE_FIX})")
    return None


def default_pulse(meta: SurveyMeta) -> np.ndarray:
    """Sample the LFM pulse described by ``meta.pulse`` at ``meta.fs``."""
    # imported here: scipy.signal costs seconds to import and `shsas info` never needs it
    from shsas_core.data.pulse import lfm_pulse

    p = meta.pulse
    return lfm_pulse(p.f_start, p.f_stop, p.duration, meta.fs, p.window, p.window_param)
