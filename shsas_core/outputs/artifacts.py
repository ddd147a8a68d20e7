"""The files a job writes into its output folder, named once for the pipeline and the service.

Torch-free on purpose: the API process reads these names (downloads, re-extraction) and must not
load the science's compute stack to do so.
"""

from __future__ import annotations


def artifact_names(method: str) -> dict[str, str]:
    """The fixed file names one method writes into ``out_dir``."""
    return {
        "volume": f"{method}_volume.npy",
        "grid": f"{method}_volume.json",
        "pointcloud": f"{method}_pointcloud.ply",
        "mesh_ply": f"{method}_mesh.ply",
        "mesh_glb": f"{method}_mesh.glb",
    }
