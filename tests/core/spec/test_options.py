"""Each option of a job is declared once: the job spec (and so the HTTP API's schema),
the CLI's help and the library configs report the same bounds and defaults."""

from __future__ import annotations

import contextlib
import io
import typing

import pytest

from shsas_core.cli.spec_options import bounds_text, option_name, value_schema
from shsas_core.neural.fields.occupancy import OccupancyConfig
from shsas_core.neural.render import RenderConfig
from shsas_core.neural.train import TrainConfig
from shsas_core.spec.job import ReconstructionSpec, spec_json_schema


def spec_schema() -> dict:
    """Field name -> the JSON schema of that spec field (as the API and the CLI read it)."""
    return spec_json_schema()["properties"]


#: Spec field -> (config, its field) that the pipeline hands the value to.
SHARED = {
    "iters": (TrainConfig, "iters"), "lr": (TrainConfig, "lr"), "lr_final": (TrainConfig, "lr_final"),
    "num_bins": (TrainConfig, "num_bins"), "num_rays": (TrainConfig, "num_rays"),
    "pings_per_batch": (TrainConfig, "pings_per_batch"), "seed": (TrainConfig, "seed"),
    "device": (TrainConfig, "device"), "target": (TrainConfig, "target"),
    "coarse_to_fine": (TrainConfig, "coarse_to_fine"),
    "occupancy_floor": (OccupancyConfig, "floor_factor"),
}
#: LossWeights.sparsity is a plain weight (>= 0, tests use 1000); the spec caps it at 100 for users.
_BOUND_KEYS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "pattern", "enum", "type")


def _bounds(prop: dict) -> dict:
    value, nullable = value_schema(prop)
    return {"nullable": nullable, **{k: value[k] for k in _BOUND_KEYS if k in value}}


@pytest.mark.parametrize("field", sorted(SHARED))
def test_spec_and_library_configs_agree(field):
    model, name = SHARED[field]
    lib = model.model_json_schema()["properties"][name]
    assert _bounds(spec_schema()[field]) == _bounds(lib)
    assert ReconstructionSpec.model_fields[field].default == model.model_fields[name].default


@pytest.mark.parametrize("field", ["num_bins", "num_rays", "uniform_fraction"])
def test_render_and_train_configs_agree(field):
    assert _bounds(RenderConfig.model_json_schema()["properties"][field]) == \
        _bounds(TrainConfig.model_json_schema()["properties"][field])
    assert RenderConfig.model_fields[field].default == TrainConfig.model_fields[field].default


def test_a_render_setting_trainconfig_owns_is_an_error_not_dropped():
    with pytest.raises(ValueError, match="render.num_rays"):
        TrainConfig(render=RenderConfig(num_rays=8))
    cfg = TrainConfig(num_rays=8, render=RenderConfig(lambertian=False))
    assert cfg.render_config().num_rays == 8 and cfg.render_config().lambertian is False


def test_train_config_passes_every_spec_option():
    from shsas_core.methods.neural import train_config

    spec = ReconstructionSpec(iters=7, lr=0.5, lr_final=0.01, num_bins=5, num_rays=6, pings_per_batch=2,
                              seed=3, device="cpu", target="envelope", sparsity=2.0, normal_window=3,
                              coarse_to_fine=0.25, angular_prior=0.7, tv_density=0.1, tv_scatter=0.2,
                              tv_phase=0.3)
    cfg = train_config(spec)
    assert cfg.render_config().normal_window == spec.normal_window
    for field, (model, name) in SHARED.items():
        if model is OccupancyConfig:  # handed to the occupancy grid, not to the trainer
            continue
        owner = cfg.render_config() if model is RenderConfig else cfg
        assert getattr(owner, name) == getattr(spec, field), field
    assert cfg.weights.sparsity == spec.sparsity
    assert cfg.weights.angular == spec.angular_prior
    assert (cfg.weights.tv_density, cfg.weights.tv_scatter, cfg.weights.tv_phase) == (0.1, 0.2, 0.3)


def test_the_lambertian_normal_is_windowed_by_default_and_the_papers_own_in_its_preset():
    # the window lights a thin shell's ridge (test_render); --preset paper keeps the sample's own
    # gradient, and both reach the renderer the trainer builds
    from shsas_core.methods.neural import train_config
    from shsas_core.spec.job import PAPER_SETTINGS
    from shsas_core.spec.options import NORMAL_WINDOW

    assert NORMAL_WINDOW > 1 and RenderConfig().normal_window == NORMAL_WINDOW
    assert train_config(ReconstructionSpec()).render_config().normal_window == NORMAL_WINDOW
    assert train_config(ReconstructionSpec(**PAPER_SETTINGS)).render_config().normal_window == 1


def _meta_survey(fs: float, band: tuple[float, float]):
    from types import SimpleNamespace

    from shsas_core.data.survey import PulseParams, SurveyMeta

    return SimpleNamespace(meta=SurveyMeta(fs=fs, pulse=PulseParams(f_start=band[0], f_stop=band[1])))


@pytest.mark.parametrize("fs, band, samples", [(100e3, (10e3, 30e3), 5), (250e3, (10e3, 30e3), 12),
                                               (100e3, (17.5e3, 22.5e3), 20), (100e3, (5e3, 45e3), 5)])
def test_the_default_normal_window_is_one_range_resolution_of_the_survey(fs, band, samples):
    # a length along the ray, not a count of samples: the whole samples in c/2B are fs / B (a
    # count of 5 was 0.4 of a resolution at 250 kHz), but never fewer than 5 (a 40 kHz band's
    # 2.5); the renderer's own default is the default survey's; a window the spec gives is kept
    import torch

    from shsas_core.methods.neural import normal_window
    from shsas_core.spec.options import NORMAL_WINDOW

    survey = _meta_survey(fs, band)
    assert normal_window(ReconstructionSpec(), torch.ones(5), survey) == samples
    assert normal_window(ReconstructionSpec(normal_window=3), torch.ones(5), survey) == 3
    assert normal_window(ReconstructionSpec(), torch.ones(5), _meta_survey(100e3, (10e3, 30e3))) == NORMAL_WINDOW


def test_the_impulse_forward_model_fits_with_the_samples_own_normal():
    # its bins are drawn apart along each ray: a window of them is no finite difference, and the
    # pre-deconvolved pings of a real folder get that model under forward = "psf" too
    from shsas_core.methods.neural import normal_window, train_config

    spec, survey = ReconstructionSpec(), _meta_survey(250e3, (10e3, 30e3))
    assert normal_window(spec, None, survey) == 1
    assert train_config(spec, normal_window(spec, None, survey)).render_config().normal_window == 1
    assert normal_window(ReconstructionSpec(normal_window=3), None, survey) == 1


def test_spec_encoding_names_the_encoding_presets():
    from shsas_core.neural.fields.encoding import PRESETS

    assert set(typing.get_args(ReconstructionSpec.model_fields["encoding"].annotation)) == set(PRESETS)


def _help(*argv: str) -> str:
    from shsas_core.cli import build_parser

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):
        build_parser().parse_args([*argv, "--help"])
    return " ".join(buf.getvalue().split())


@pytest.mark.parametrize("command", [["reconstruct"], ["demo"]])
def test_every_spec_field_is_an_option_with_the_spec_bounds_and_default(command):
    """Adding a spec field adds the option; its help shows the schema's bounds and default."""
    text = _help(*command).split("reconstruction spec (defaults", 1)[1]
    for field, prop in spec_schema().items():
        opt = option_name(field)
        assert f" {opt} " in text, opt
        entry = text.split(f" {opt} ", 1)[1].split(" --", 1)[0]
        value = value_schema(prop)[0]
        span = bounds_text(value)
        if span:
            assert f"in {span}" in entry, (opt, entry)
        if field != "methods":
            default = prop.get("default")
            assert f"(default {'none' if default is None else default})" in entry, (opt, entry)


def test_api_schema_is_the_spec_schema():
    """The API serves the spec's own schema (with factory defaults filled in), the one the CLI reads."""
    pytest.importorskip("fastapi")
    from service.routes.console import reconstruction_spec_schema

    assert reconstruction_spec_schema() == spec_json_schema()
    assert spec_schema()["methods"]["default"] == ["backprojection", "reed", "shsas"]


def test_cli_grid_bounds_are_the_spec_bounds(tmp_path):
    from shsas_core.cli import main

    lo, hi = (spec_schema()["grid"]["anyOf"][0][k] for k in ("minimum", "maximum"))
    for bad in (lo - 1, hi + 1):
        assert main(["backproject", str(tmp_path / "x.h5"), "--grid", str(bad), "--out", str(tmp_path)]) == 2
        assert main(["reconstruct", str(tmp_path / "x.h5"), "--grid", str(bad), "--out", str(tmp_path)]) == 2


def test_the_spec_methods_are_the_registry():
    from shsas_core.spec.catalogue import DEFAULT_METHODS, NEURAL, REGISTRY
    from shsas_core.spec.job import METHODS, Method

    assert typing.get_args(Method) == tuple(REGISTRY) == METHODS
    assert tuple(ReconstructionSpec().methods) == DEFAULT_METHODS == ("backprojection", "reed", "shsas")
    assert [REGISTRY[m].sh_degree(2) for m in DEFAULT_METHODS] == [None, 0, 2]
    assert NEURAL[:2] == ("reed", "shsas")


def test_building_the_cli_does_not_import_torch():
    """`shsas worker` / `serve` parse their options in a process that must not load torch (the
    Celery parent; tests/service/test_celery.py checks its memory maps)."""
    import subprocess
    import sys

    code = "import sys; from shsas_core.cli import build_parser; build_parser(); print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
