"""Resume bookkeeping of one reconstruction job: what the pipeline keeps under
``out_dir/checkpoints`` so a re-delivered or re-run job picks up where it stopped.

Layout (every file written atomically)::

    checkpoints/run_key.json             the spec (without the extraction fields) + the survey digest
    checkpoints/deconvolved.npy          (N, T) complex64 s_PD of all pings
    checkpoints/backprojection_image.npy the training pings' image on the job's grid
    checkpoints/<method>/checkpoint.pt   the trainer's checkpoint (shsas_core.neural.train)
    checkpoints/<method>/signal_fit.npz  the signal-fit figure of a neural method
    checkpoints/<method>/extract.json    the extraction settings the method's outputs were made with
    checkpoints/<method>/done.json       the method's report entry: the method is finished

A different spec or survey clears the folder; a changed extraction (``spec.EXTRACTION_FIELDS`` or
the extraction code version) keeps the reconstructions and redoes only the extraction. The pipeline decides what to compute;
this module only says what is already there.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from shsas_core.common.atomic import atomic_path
from shsas_core.data.survey import Survey
from shsas_core.outputs.export import write_json, write_text
from shsas_core.outputs.report import MethodReport, SignalFit
from shsas_core.spec.job import EXTRACTION_FIELDS, ReconstructionSpec


def survey_fingerprint(survey: Survey) -> str:
    """A digest of the survey's geometry, metadata and samples (resume key)."""
    h = hashlib.sha256()
    h.update(survey.meta.model_dump_json().encode())
    for a in (survey.tx, survey.rx, survey.t0, survey.samples, survey.gt_vertices):
        if a is not None:
            h.update(str(a.shape).encode())
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


class MethodCache:
    """One method's folder under the job's checkpoints."""

    def __init__(self, folder: Path):
        self.folder = folder

    def finished(self) -> MethodReport | None:
        """The report entry of a finished method, else None."""
        p = self.folder / "done.json"
        return MethodReport.model_validate_json(p.read_text()) if p.exists() else None

    def extracted_with(self, key: dict[str, Any]) -> bool:
        """Whether the method's outputs were extracted with these settings."""
        return _read_json(self.folder / "extract.json") == key

    def mark_done(self, report: MethodReport, extract_key: dict[str, Any]) -> None:
        write_json(extract_key, self.folder / "extract.json")
        write_text(report.model_dump_json(indent=2), self.folder / "done.json")

    def save_fit(self, fit: SignalFit) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.folder / "signal_fit.npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, times=fit.times, measured=fit.measured, predicted=fit.predicted,
                     pings=np.asarray(fit.pings))

    def load_fit(self) -> SignalFit | None:
        p = self.folder / "signal_fit.npz"
        if not p.exists():
            return None
        with np.load(p, allow_pickle=False) as z:
            return SignalFit(z["times"], z["measured"], z["predicted"], [int(i) for i in z["pings"]])


def _same_run(stored: Any, key: dict[str, Any]) -> bool:
    """Whether a stored run key names the run ``key`` does. A spec field added since the key was
    written is absent from it and counts at its default: a new field's default keeps the
    behaviour from before the field (so adding one does not discard every job's checkpoints)."""
    if not isinstance(stored, dict) or not isinstance(stored.get("spec"), dict):
        return stored == key
    defaults = ReconstructionSpec().model_dump(mode="json", exclude=set(EXTRACTION_FIELDS))
    spec = {**{k: v for k, v in defaults.items() if k not in stored["spec"]}, **stored["spec"]}
    return {**stored, "spec": spec} == key


class JobCache:
    """The checkpoints folder of one job, opened for one (spec, survey).

    Args:
        folder: ``out_dir/checkpoints``.
        spec, survey: the job; checkpoints made for another spec (the threshold aside) or survey
            are removed.
    """

    def __init__(self, folder: Path, spec: ReconstructionSpec, survey: Survey):
        self.folder = folder
        # the extraction fields only affect extraction, which is redone from the saved volume,
        # so changing them keeps the reconstructions
        key = {"spec": spec.model_dump(mode="json", exclude=set(EXTRACTION_FIELDS)),
               "survey": survey_fingerprint(survey)}
        kp = folder / "run_key.json"
        if kp.exists() and not _same_run(_read_json(kp), key):
            shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir(parents=True, exist_ok=True)
        if not kp.exists():
            write_json(key, kp)

    def array(self, name: str, shape: tuple[int, ...]) -> np.ndarray | None:
        """A saved array ``<name>.npy`` of this shape, else None."""
        p = self.folder / f"{name}.npy"
        if p.exists():
            arr = np.load(p, allow_pickle=False)
            if arr.shape == tuple(shape):
                return arr
        return None

    def save_array(self, name: str, arr: np.ndarray) -> None:
        with atomic_path(self.folder / f"{name}.npy") as tmp, open(tmp, "wb") as fh:
            np.save(fh, arr)

    def method(self, name: str) -> MethodCache:
        return MethodCache(self.folder / name)
