"""The suite's own scheduling rule (tests/schedule.py, applied by tests/conftest.py): modules with
a slow test go first."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

from tests.run_suite import ROOT, SCIENCE, suite_env
from tests.schedule import slow_modules_first


class FakeItem:
    def __init__(self, module: str, slow: bool) -> None:
        self.module = types.SimpleNamespace(__name__=module)
        self.slow = slow

    def get_closest_marker(self, name: str) -> object | None:
        return object() if name == "slow" and self.slow else None


def test_modules_with_a_slow_test_go_first_whole_and_in_order() -> None:
    items = [FakeItem("a", False), FakeItem("b", False), FakeItem("b", True), FakeItem("c", False),
             FakeItem("d", True), FakeItem("d", False)]
    got = [(i.module.__name__, i.slow) for i in slow_modules_first(items)]  # type: ignore[arg-type]
    assert got == [("b", False), ("b", True), ("d", True), ("d", False), ("a", False), ("c", False)]


def test_the_science_run_starts_the_module_of_a_slow_test_first(tmp_path: Path) -> None:
    """With run_suite's options on two xdist workers, a one-test module holding a slow test is
    the first handed out, ahead of modules with more (fast) tests; xdist's default reordering,
    by number of tests, handed it out last."""
    log = tmp_path / "starts.log"
    (tmp_path / "pytest.ini").write_text("[pytest]\nmarkers =\n    slow: long\n    gpu: CUDA\n    service: servers\n")
    (tmp_path / "conftest.py").write_text("from tests.schedule import order_items\n\n\n"
                                          "def pytest_collection_modifyitems(config, items):\n"
                                          "    order_items(items)\n")
    record = "    open(os.environ['STARTS'], 'a').write(f'{time.monotonic_ns()} {__name__}\\n')\n    time.sleep(0.05)\n"
    for name in ("test_a_many", "test_b_many"):
        body = "".join(f"def test_{i}():\n{record}\n" for i in range(5))
        (tmp_path / f"{name}.py").write_text(f"import os\nimport time\n\n{body}")
    (tmp_path / "test_z_slow.py").write_text(f"import os\nimport time\n\nimport pytest\n\n@pytest.mark.slow\ndef test_long():\n{record}")
    env = {**os.environ, "STARTS": str(log), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *SCIENCE, str(tmp_path)],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    starts = [line.split()[1] for line in sorted(log.read_text().splitlines(), key=lambda s: int(s.split()[0]))]
    assert len(starts) == 11 and "test_z_slow" in starts[:2], starts


def test_both_runs_wait_passively_in_openmp_unless_told_otherwise() -> None:
    assert suite_env({"PATH": "/bin"}) == {"PATH": "/bin", "OMP_WAIT_POLICY": "PASSIVE"}
    assert suite_env({"OMP_WAIT_POLICY": "ACTIVE"})["OMP_WAIT_POLICY"] == "ACTIVE"  # the caller's own


def test_the_service_run_gives_its_jobs_one_thread_unless_told_otherwise() -> None:
    assert suite_env({}, service=True) == {"OMP_WAIT_POLICY": "PASSIVE", "SHSAS_WORKER_THREADS": "1"}
    assert suite_env({"SHSAS_WORKER_THREADS": "2"}, service=True)["SHSAS_WORKER_THREADS"] == "2"
    assert "SHSAS_WORKER_THREADS" not in suite_env({})  # the science run's tests read the default
