"""A reconstruction method from outside the project, installed as a distribution would install it.

:func:`install_toy_method` writes into a folder a module and a ``.dist-info`` whose
``entry_points.txt`` adds the method ``toy`` to the ``shsas.methods`` group; a process started
with that folder on ``PYTHONPATH`` has the method in its catalogue (CLI choices, spec, API schema,
``GET /methods``) and runs it, with no file of the project edited. The toy's volume is the squared
magnitude of the job's backprojection image, so a test can check it against the backprojection's.
"""

from __future__ import annotations

from pathlib import Path

TOY = "toy"
TOY_COLOUR = "#ff00ff"

_MODULE = '''
"""The toy method: the squared magnitude of the job's backprojection image."""

import numpy as np

from shsas_core.spec.catalogue import MethodKind

KIND = MethodKind("toy", cost=0.1, neural=False, implementation=__name__, label="Toy (|backprojection|^2)",
                  colour="#ff00ff")


def reconstruct(ctx):
    from shsas_core.common.progress import sub_progress
    from shsas_core.data.volume import Volume
    from shsas_core.methods import MethodResult

    image = ctx.image(sub_progress(ctx.progress, 0.0, 0.8))
    return MethodResult(volume=Volume(ctx.grid, (np.abs(image.values) ** 2).astype(np.float32), name="toy"))
'''


def install_toy_method(folder: Path) -> Path:
    """Write the toy method's module and its distribution metadata into ``folder``; returns it."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "shsas_toy_method.py").write_text(_MODULE)
    info = folder / "shsas_toy_method-0.1.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: shsas-toy-method\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[shsas.methods]\n{TOY} = shsas_toy_method:KIND\n")
    return folder
