"""Rendering pings from a scattering field: ellipsoidal sampling, transmittance, transients.

Submodules: :mod:`.geometry` (constant-ToF ellipsoids, ray intersection), :mod:`.sampling`
(range bins, beam-cone rays), :mod:`.transmittance`, :mod:`.renderer` (the forward model,
novel-view transients, signal errors). See docs/neural.md.
"""

from shsas_core.neural.render.geometry import (
    area_jacobian,
    ellipsoid_frame,
    intersect_focal,
    intersect_quadric,
    points_on_rays,
)
from shsas_core.neural.render.renderer import (
    PingGeometry,
    RenderConfig,
    passband_factor,
    ping_geometry,
    render_pings,
    render_samples,
    render_transients,
    sample_ellipsoids,
    signal_errors,
)
from shsas_core.neural.render.sampling import (
    beam_axes,
    bin_radii,
    cone_directions,
    cone_half_angles,
    sample_bins,
)
from shsas_core.neural.render.transmittance import (
    optical_depth,
    transmittance,
    transmittance_cumprod,
)

__all__ = [
    "PingGeometry", "RenderConfig", "area_jacobian", "beam_axes", "bin_radii", "cone_directions",
    "cone_half_angles", "ellipsoid_frame", "intersect_focal", "intersect_quadric", "optical_depth",
    "passband_factor", "ping_geometry", "points_on_rays", "render_pings", "render_samples", "render_transients",
    "sample_bins", "sample_ellipsoids", "signal_errors", "transmittance",
    "transmittance_cumprod",
]
