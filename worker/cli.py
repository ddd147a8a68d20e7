"""`shsas worker`: a Celery worker process that runs reconstruction jobs from Redis."""

from __future__ import annotations

import argparse
import os
import socket


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "worker", help="run a Celery worker (needs SHSAS_BROKER_URL); one per GPU",
        description="Run one Celery worker process that executes reconstruction jobs from the broker "
        "in SHSAS_BROKER_URL (Redis), writing progress to the job store in SHSAS_DATABASE_URL and outputs "
        "to SHSAS_DATA_DIR (shared with the API). Concurrency is 1 and prefetch 1: start one worker per "
        "GPU, each with --gpu N. The task runs in the pool child, the only process that touches CUDA. "
        "Also runs the reconciler that re-queues jobs whose worker was lost.")
    p.add_argument("--queues", "-Q", help="comma-separated queues (default: SHSAS_GPU_QUEUE,SHSAS_CPU_QUEUE)")
    p.add_argument("--gpu", help="GPU index this worker owns (sets CUDA_VISIBLE_DEVICES for the worker)")
    p.add_argument("--name", help="Celery node name (default shsas-<pid>@<host>)")
    p.add_argument("--no-reconcile", action="store_true", help="do not run the stale-lease reconciler here")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.common.errors import ShsasError

    if args.gpu is not None:
        if not args.gpu.isdigit():
            raise ShsasError(f"--gpu: expected a GPU index like 0, got {args.gpu!r}")
        os.environ["CUDA_VISIBLE_DEVICES"] = args.gpu
    try:
        from jobs.settings import get_settings
    except ImportError as exc:
        raise ShsasError(f"worker: the service extra is not installed ({exc.name}); "
                         "pip install 'shsas[service]'") from None
    settings = get_settings()
    if not settings.broker_url:
        raise ShsasError("worker: SHSAS_BROKER_URL is not set; `shsas serve` runs its own local worker in "
                         "that case (set SHSAS_BROKER_URL=redis://host:6379/0 for separate workers)")
    from jobs.store import JobStore
    from worker.app import app
    from worker.logs import configure_logging
    from worker.reconciler import Reconciler

    configure_logging(settings.log_format, args.log_level)  # pool children inherit it (fork)

    rec = None if args.no_reconcile else Reconciler(JobStore.from_settings(settings), settings).start()
    queues = args.queues or f"{settings.gpu_queue},{settings.cpu_queue}"
    name = args.name or f"shsas-{os.getpid()}@{socket.gethostname()}"
    try:
        app.worker_main(["worker", "-Q", queues, "-c", "1", "--prefetch-multiplier", "1", "-n", name,
                         "-l", args.log_level, "--without-gossip", "--without-mingle"])
    finally:
        if rec:
            rec.stop()
    return 0
