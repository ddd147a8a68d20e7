"""bench_variants refuses what it cannot run, naming it, before simulating anything."""

from __future__ import annotations

import pytest

from tests.helpers.bench_scripts import load_bench

bench_variants = load_bench("bench_variants")


@pytest.mark.parametrize(("argv", "named"), [
    (["--variants", "reference,ultrasound"], "ultrasound"),
    (["--methods", "backprojection,nerf"], "nerf"),
    (["--mesh", "/no/such/mesh.obj"], "/no/such/mesh.obj"),
    (["--spec", '{"sparsity": -1}'], "sparsity"),
    (["--spec", '{"sparsty": 0}'], "sparsty"),
])
def test_bad_arguments_exit_with_the_name(argv: list[str], named: str, tmp_path, capsys) -> None:
    from shsas_core.simulation.variants import VARIANTS

    # a name that became a variant would run the whole benchmark here instead of refusing it
    assert named not in VARIANTS
    with pytest.raises(SystemExit) as exc:
        bench_variants.main([*argv, "--out", str(tmp_path)])
    assert exc.value.code == 2
    assert named in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
