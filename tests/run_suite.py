"""Run the whole suite (``make test``): the service tests and, beside them, the science tests at
the lowest CPU priority.

Why side by side: the service tests spend much of their time waiting (for a server to answer, a
worker to pick a job up, a lease to run out, a browser to draw), so run alone they keep about
one of two cores busy; the science tests are CPU-bound. Run one after the other, the suite took
the sum of both. Why the lowest priority: the service tests' processes (API servers, job
workers, Chromium) must get a core when they want one, or their polls and deadlines stretch;
the science tests only fill the time those leave idle.

On Linux ``nice`` alone is not enough: with the scheduler's autogroups (``sched_autogroup``, on
by default) niceness only ranks processes within one session, and every server the service tests
start runs in a session of its own. So the science run gets a session of its own too, and that
session's autogroup is set to niceness 19 (``/proc/self/autogroup``; where the file is missing,
plain ``nice`` is what counts).

Why OpenMP waits passively here: a job the service tests run sizes torch's OpenMP pool to both
cores, and libgomp's default lets a thread that reaches a barrier spin on its core for a while
before it sleeps. With the science run on that core, the spinning thread only burns the time the
other run needs. ``OMP_WAIT_POLICY=PASSIVE`` (unless the caller set a policy) makes waiting
threads sleep (docs/architecture.md has the suite's timings with and without).

Why the service run's jobs get one thread (``SHSAS_WORKER_THREADS=1``, unless the caller set
it): several service tests watch a job that would train for hours (status, ETA, a worker killed
mid-job) and cancel it. Such a job takes every core its pool has for as long as it is watched,
and from the scheduler's point of view its server's session outranks the science run. With one
thread it leaves the other core to the science tests; nothing it is watched for depends on it.

Usage: ``python tests/run_suite.py [extra pytest options for both runs]``. Exits non-zero when
either run fails; the science run's output follows the service run's.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: The science tests on two pytest-xdist workers (one torch thread each, tests/conftest.py);
#: --dist loadfile keeps each module on one worker, so a module fixture is built once.
#: --no-loadscope-reorder: xdist otherwise hands out modules by number of tests, most first, so
#: the modules of one or two long tests (the identity chain, the warm-start guarantee) came last
#: and ran alone while the other worker idled; tests/schedule.py's order (slow modules first) holds.
SCIENCE = ["-m", "not service", "-n", "2", "--dist", "loadfile", "--no-loadscope-reorder"]
SERVICE = ["-m", "service"]
LOWEST = 19
#: OpenMP settings both runs and the processes they start inherit (module doc)
OPENMP_ENV = {"OMP_WAIT_POLICY": "PASSIVE"}
#: ... and what the service run adds (module doc)
SERVICE_ENV = {"SHSAS_WORKER_THREADS": "1"}


def _lowest_priority() -> None:
    """In the science child, after its new session is made and before exec: that session's
    autogroup and the process at the lowest priority (module doc)."""
    with contextlib.suppress(OSError):
        Path("/proc/self/autogroup").write_text(str(LOWEST))
    with contextlib.suppress(OSError):
        os.nice(LOWEST)


def suite_env(environ: Mapping[str, str], service: bool = False) -> dict[str, str]:
    """The environment of a run: ``environ`` with :data:`OPENMP_ENV` (and for the service run
    :data:`SERVICE_ENV`) where it sets none of them."""
    return {**OPENMP_ENV, **(SERVICE_ENV if service else {}), **environ}


def main(argv: list[str]) -> int:
    pytest = [sys.executable, "-m", "pytest", "-q", *argv]
    with tempfile.TemporaryFile(mode="w+") as science_log:
        science = subprocess.Popen([*pytest, *SCIENCE], cwd=ROOT, stdout=science_log,
                                   stderr=subprocess.STDOUT, start_new_session=True,
                                   preexec_fn=_lowest_priority, env=suite_env(os.environ))
        try:
            service_rc = subprocess.call([*pytest, *SERVICE], cwd=ROOT, env=suite_env(os.environ, service=True))
            science_rc = science.wait()
        finally:
            if science.poll() is None:  # interrupted: the science run's whole session goes too
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(science.pid, signal.SIGTERM)
                science.wait()
        science_log.seek(0)
        print("\n== science tests (run beside the service tests, at the lowest CPU priority)", flush=True)
        sys.stdout.write(science_log.read())
    for name, rc in (("service", service_rc), ("science", science_rc)):
        if rc != 0:
            print(f"run_suite: the {name} tests failed (pytest exit code {rc})", file=sys.stderr)
    return 0 if service_rc == 0 and science_rc == 0 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
