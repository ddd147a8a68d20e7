"""Neural scattering field of SH-SAS: hash encoding, real SH basis, and the SH field.

Entry points: :class:`HashEncoding` / :class:`HashEncodingConfig` (presets ``CPU_ENCODING``,
``PAPER_GPU_ENCODING``), :func:`sh_basis`, :class:`SHField` / :class:`FieldConfig`.
"""

from shsas_core.neural.fields.base import ScatteringField, device_dtype
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.fields.encoding import (
    CPU_ENCODING,
    PAPER_GPU_ENCODING,
    SMALL_ENCODING,
    HashEncoding,
    HashEncodingConfig,
    encode_fused,
    encode_reference,
    encoding_preset,
)
from shsas_core.neural.fields.field import SHField, normals_by_autograd, safe_normalize
from shsas_core.neural.fields.sh import angular_roughness, num_coefficients, sh_basis, sh_index

__all__ = [
    "CPU_ENCODING",
    "PAPER_GPU_ENCODING",
    "SMALL_ENCODING",
    "FieldConfig",
    "HashEncoding",
    "HashEncodingConfig",
    "SHField",
    "ScatteringField",
    "angular_roughness",
    "device_dtype",
    "encode_fused",
    "encode_reference",
    "encoding_preset",
    "normals_by_autograd",
    "num_coefficients",
    "safe_normalize",
    "sh_basis",
    "sh_index",
]
