"""`shsas serve`: the HTTP API, plus the embedded local worker when no broker is configured."""

from __future__ import annotations

import argparse
import os
import signal


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve", help="run the HTTP API (and, without SHSAS_BROKER_URL, a local worker)",
        description="Start the shsas HTTP service (FastAPI; OpenAPI docs at /docs). Configuration comes "
        "from SHSAS_* environment variables (see docs/service.md): data in SHSAS_DATA_DIR, jobs in "
        "SHSAS_DATABASE_URL (default: SQLite in the data dir). With SHSAS_BROKER_URL unset this one "
        "command is the whole service: jobs queue in the job table and a local worker child process "
        "runs them. With SHSAS_BROKER_URL=redis://... it serves the API only and `shsas worker` "
        "processes run the jobs. Needs the 'service' extra (pip install shsas[service]).")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1; without API keys "
                   "only loopback clients are served)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    p.add_argument("--data-dir", help="overrides SHSAS_DATA_DIR")
    p.add_argument("--workers", type=int, help="API processes sharing the port (overrides SHSAS_API_WORKERS, "
                   "default 1); the embedded worker runs at lower priority than all of them")
    p.add_argument("--no-worker", action="store_true", help="do not start the embedded local worker")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from shsas_core.common.errors import ShsasError

    if args.data_dir:
        os.environ["SHSAS_DATA_DIR"] = args.data_dir
    try:
        import uvicorn

        from jobs.settings import get_settings
        from service.app import SERVE_PID_ENV, create_app
        from service.http_guard import GuardedHttpToolsProtocol, raise_fd_limit
        from worker.local import LocalWorkerSupervisor
    except ImportError as exc:
        raise ShsasError(f"serve: the service extra is not installed ({exc.name}); "
                         "pip install 'shsas[service]'") from None
    import pydantic

    try:
        settings = get_settings()
    except pydantic.ValidationError as exc:
        err = exc.errors()[0]
        raise ShsasError(f"settings: SHSAS_{'_'.join(map(str, err['loc'])).upper()}: {err['msg']}") from None
    from worker.logs import configure_logging

    configure_logging(settings.log_format, args.log_level)
    if args.workers is not None and args.workers < 1:
        raise ShsasError(f"serve: --workers must be at least 1 (got {args.workers})")
    app = create_app(settings)
    # uvicorn shuts down gracefully on SIGTERM, then re-raises it with the handler it found:
    # the default one would end this process before the `finally` below stops the worker.
    signal.signal(signal.SIGTERM, _exit_on_term)
    sup = None
    try:
        sup = LocalWorkerSupervisor().start() if settings.embedded and not args.no_worker else None
        mode = "embedded local worker" if sup else ("broker " + settings.broker_url.split("@")[-1]
                                                    if settings.broker_url else "no worker")
        print(f"shsas serve: http://{args.host}:{args.port}/docs  data={settings.data_dir}  ({mode})", flush=True)
        workers = args.workers or settings.api_workers
        raise_fd_limit(settings)
        os.environ[SERVE_PID_ENV] = str(os.getpid())  # its API processes die with it
        # One API process gets the app built here; several each build their own (an import
        # string and a factory is what uvicorn's worker processes need).
        uvicorn.run(app if workers == 1 else "service.app:_app_from_env", factory=workers > 1,
                    workers=workers, host=args.host, port=args.port, log_level=args.log_level,
                    access_log=False, http=GuardedHttpToolsProtocol,
                    timeout_keep_alive=settings.http_keepalive_s)
    finally:
        if sup:
            sup.stop()
    return 0


def _exit_on_term(signum: int, _frame: object) -> None:
    """SIGTERM is a requested stop: unwind (stopping the local worker) and exit 0."""
    raise SystemExit(0)
