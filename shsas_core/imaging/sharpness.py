"""Image sharpness: the focus measures autofocus maximises and the focus-height search uses.

Both work on the intensity ``|I|²`` of a complex (or magnitude) image of any shape:

* ``entropy``: ``H = -Σ p log p`` with ``p = |I|² / Σ|I|²`` (nats). A focused image puts its
  energy in few pixels, so *lower* is sharper (the usual SAS autofocus measure, Fienup 2000).
* ``contrast``: ``K = N Σ|I|⁴ / (Σ|I|²)²``, the normalised fourth moment: 1 for a flat image,
  N for a single bright pixel; *higher* is sharper.

:func:`focus_cost` turns either into a cost to minimise, so the searches need not care which.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

Sharpness = Literal["entropy", "contrast"]


def _intensity(image: np.ndarray) -> np.ndarray:
    a = np.abs(np.asarray(image, dtype=np.complex128 if np.iscomplexobj(image) else np.float64))
    return (a * a).ravel()


def image_entropy(image: np.ndarray) -> float:
    """Entropy of the normalised intensity, nats (0 for one bright pixel, log N for a flat image).

    An all-zero image has no focus at all: it gets the flat image's ``log N``.
    """
    q = _intensity(image)
    total = float(q.sum())
    if total <= 0 or not np.isfinite(total):
        return float(np.log(max(q.size, 1)))
    p = q[q > 0] / total
    return float(-(p * np.log(p)).sum())


def image_contrast(image: np.ndarray) -> float:
    """Normalised fourth moment ``N Σ|I|⁴ / (Σ|I|²)²`` (1 flat, N one pixel; 0 for all zeros)."""
    q = _intensity(image)
    total = float(q.sum())
    if total <= 0 or not np.isfinite(total):
        return 0.0
    return float(q.size * (q * q).sum() / (total * total))


def focus_cost(image: np.ndarray, measure: Sharpness = "entropy") -> float:
    """A cost that falls as the image sharpens: the entropy, or minus the log contrast."""
    if measure == "entropy":
        return image_entropy(image)
    return -float(np.log(max(image_contrast(image), 1e-300)))
