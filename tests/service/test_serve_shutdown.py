"""`shsas serve` takes its embedded local worker down with it.

A real `shsas serve` subprocess: SIGTERM or SIGINT to the serve process alone (not its process
group, as `kill PID` or a service manager that signals only the main pid would) must stop the
worker child and multiprocessing's resource tracker within a few seconds; after a SIGKILL of
serve, which runs no handler at all, the worker must notice its parent is gone and exit within
10 s instead of taking jobs as an orphan.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from .conftest import FAST_TIMINGS, start_server

pytestmark = pytest.mark.service


def _alive(pid: int) -> bool:
    """True while ``pid`` runs; a zombie waiting for a reaper counts as gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat.rsplit(")", 1)[1].split()[0] not in ("Z", "X")


def _children(pid: int) -> dict[int, str]:
    """pid -> command line of the direct children of ``pid``."""
    out: dict[int, str] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            cmd = Path(f"/proc/{child}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            out[int(child)] = cmd
    return out


def _worker_and_tracker(serve_pid: int) -> tuple[int, int | None]:
    """(local worker pid, resource tracker pid or None) among serve's children."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        kids = _children(serve_pid)
        worker = [p for p, cmd in kids.items() if "spawn_main" in cmd]
        tracker = [p for p, cmd in kids.items() if "resource_tracker" in cmd]
        if worker:
            return worker[0], (tracker[0] if tracker else None)
        time.sleep(0.2)
    raise AssertionError(f"no local worker child of serve pid {serve_pid}: {_children(serve_pid)}")


def _gone_within(pids: list[int], seconds: float) -> list[int]:
    """The pids still alive after ``seconds`` (polling; returns early once all are gone)."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        alive = [p for p in pids if _alive(p)]
        if not alive:
            return []
        time.sleep(0.1)
    return [p for p in pids if _alive(p)]


@pytest.fixture
def serve(tmp_path: Path):
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data"), **FAST_TIMINGS}
    proc, _ = start_server(tmp_path, env)
    worker, tracker = _worker_and_tracker(proc.pid)
    yield proc, worker, tracker
    proc.stop()  # clears serve's process group, which the orphan (if any) still belongs to


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_signal_to_serve_stops_its_local_worker(serve, sig: int) -> None:
    proc, worker, tracker = serve
    os.kill(proc.pid, sig)  # the serve process only, like `kill PID`
    proc.p.wait(15)
    left = _gone_within([worker] + ([tracker] if tracker else []), 5)
    assert not left, f"still running after serve got {sig.name}: {left}\n{proc.tail()}"
    assert proc.p.returncode == 0, proc.tail()  # a requested stop is not an error


@pytest.mark.slow
def test_sigkilled_serve_leaves_no_orphan_worker(serve) -> None:
    proc, worker, tracker = serve
    os.kill(proc.pid, signal.SIGKILL)  # no handler runs in serve
    proc.p.wait(5)
    left = _gone_within([worker] + ([tracker] if tracker else []), 10)
    assert not left, f"orphans still running 10 s after serve was SIGKILLed: {left}\n{proc.tail()}"
