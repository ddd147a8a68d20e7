"""The configuration of a neural scattering field: SH degree, hash encoding, MLP, scene box.

Its own module so that the field interface (:mod:`.base`) and the field (:mod:`.field`) both
read it without importing each other.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from shsas_core.data.survey import SceneBox
from shsas_core.neural.fields.encoding import CPU_ENCODING, Backend, HashEncodingConfig
from shsas_core.neural.fields.sh import num_coefficients
from shsas_core.spec.options import SH_DEGREE, SHDegree


class FieldConfig(BaseModel):
    """Configuration of :class:`SHField`. Defaults train on a 2-core CPU."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sh_degree: SHDegree = SH_DEGREE
    encoding: HashEncodingConfig = CPU_ENCODING
    hidden: int = Field(32, ge=1, le=1024, description="units per hidden layer")
    layers: int = Field(2, ge=1, le=8, description="hidden layers (ReLU)")
    scene_box: SceneBox = SceneBox()
    zeta: float = Field(1.0, gt=0, description="occlusion scale ζ: density = |σ_DC| ζ")
    init_density: float = Field(
        1e-2, gt=0, description="density at initialisation (1/m), from the bias of Re c_00"
    )
    directional_scale: float = Field(
        0.1, gt=0, le=1.0, description="the degree >= 1 coefficients are the MLP's outputs times this "
        "factor (a per-coefficient step size for Adam; 1.0: plain outputs), see the module docstring")
    backend: Backend = Field(
        "native", description="reference (loop encoding, autograd normals: the oracle), fused (batched "
        "encoding + analytic normals), native (fused + the device's encoding kernel: C on float32 CPU, "
        "built on first use, Triton on CUDA; fused without either), triton (fused + the Triton "
        "kernels always: CUDA, or CPU under TRITON_INTERPRET=1) or compiled (fused through "
        "torch.compile); same maths")

    @property
    def num_coefficients(self) -> int:
        return num_coefficients(self.sh_degree)
