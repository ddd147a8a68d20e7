"""Service benchmark: status polling under load, and a large upload. Prints figures, never asserts.

1. Upload: a canonical survey of ``--upload-gb`` GB (default 1) to a `shsas serve --no-worker`
   server: MB/s for the upload alone (a request with an invalid spec, refused only after the
   whole body is on disk and hashed) and end to end to 202 (upload + validation in the child
   process), and the API process's peak RSS growth (VmHWM after minus VmRSS before; the
   validation child is a separate process and not included). Goal: < 100 MB.
2. Polling: ``--clients`` (default 100) concurrent clients on loopback polling
   GET /reconstructions/{id} of a running job for ``--seconds`` (default 30) on an embedded
   server (API + local worker training the job). Closed loop (each client sends its next
   request as soon as the last one answered, a minimal raw HTTP client) and, with
   ``--interval`` (default 1 s), paced: each client one request per interval on a fixed
   schedule, sent with an ``httpx.AsyncClient``. Prints requests/s, p50, p99, max, the
   niceness and thread counts of the API and of the worker, and their CPU use.
   Goal: paced p99 < 50 ms for 100 pollers at 1 request/s with a job training,
   on an idle 2-core machine. ``SHSAS_WORKER_NICE=0`` in the environment runs the worker at the
   API's priority, for comparison.

3. Soak (``--soak``, instead of 1 and 2): an embedded server (``--api-workers`` API processes,
   the local worker training a job) under ``--soak-seconds`` (default 1800) of mixed traffic:
   ``--clients`` paced pollers of the job's status (one GET per ``--interval`` each) plus one
   hostile client cycling through slowloris connections, oversized and endless headers, junk
   and truncated multipart bodies, non-surveys, zip archives of junk, bad keys, unknown ids and
   HEAD/DELETE on them, and valid tiny submissions cancelled and deleted at once. Prints the 5xx
   count (pollers and hostile client), the temporary bytes left behind (the server's private
   TMPDIR plus ``uploads/``, after the traffic stops), the API's RSS at start and end (all API
   processes) and the pollers' p50/p99. Goal: no 5xx, no leaked bytes, RSS within
   300 MiB of its start, poll p99 < 100 ms on an otherwise idle 2-core machine.

    PYTHONPATH=$PWD python benchmarks/bench_service.py [--seconds 30] [--clients 100] [--upload-gb 1]
    PYTHONPATH=$PWD python benchmarks/bench_service.py --upload-gb 0 --closed-loop 0   # the paced figure only
    PYTHONPATH=$PWD python benchmarks/bench_service.py --soak [--soak-seconds 1800] [--api-workers 2]

The client runs on the same machine as the server and competes with it for CPU.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from shsas_core.data.survey import SurveyMeta, default_pulse  # noqa: E402
from shsas_core.formats.hdf5 import FORMAT_NAME, SCHEMA_VERSION  # noqa: E402

LONG_SPEC = {"methods": ["shsas"], "iters": 200000, "grid": 16, "device": "cpu", "num_rays": 16, "num_bins": 8}


def free_port() -> int:
    with contextlib.closing(socket.socket()) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_big_survey(path: Path, gigabytes: float, samples_per_ping: int = 65536) -> int:
    """A valid canonical survey of about ``gigabytes`` GB, written block by block (bounded memory)."""
    n = max(1, int(gigabytes * 1e9 / (4 * samples_per_ping)))
    meta = SurveyMeta(platform="bench")
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    tx = np.stack([0.85 * np.cos(ang), 0.85 * np.sin(ang), np.full(n, 0.3)], 1)
    rng = np.random.default_rng(0)
    with h5py.File(path, "w") as f:
        f.attrs["format"] = FORMAT_NAME
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["meta"] = meta.model_dump_json()
        g = f.create_group("pings")
        g["tx"] = tx
        g["rx"] = tx + np.array([0.0, 0.0, -0.038])
        g["t0"] = np.full(n, 3e-3)
        ds = g.create_dataset("samples", shape=(n, samples_per_ping), dtype=np.float32)
        block = rng.standard_normal((256, samples_per_ping)).astype(np.float32)
        for start in range(0, n, 256):
            stop = min(start + 256, n)
            ds[start:stop] = block[: stop - start]
        f.create_group("pulse")["samples"] = default_pulse(meta)
    return path.stat().st_size


def start_server(data: Path, log: Path, *extra: str, env_extra: dict[str, str] | None = None
                 ) -> tuple[subprocess.Popen, str]:
    port = free_port()
    env = {**os.environ, "PYTHONPATH": str(REPO), "SHSAS_DATA_DIR": str(data),
           "SHSAS_MAX_UPLOAD_BYTES": str(8 * 1024**3), "SHSAS_VALIDATE_MEMORY_BYTES": str(2 * 1024**3),
           **(env_extra or {})}
    env.pop("SHSAS_BROKER_URL", None)
    env.pop("SHSAS_DATABASE_URL", None)
    proc = subprocess.Popen([sys.executable, "-m", "shsas_core.cli", "serve", "--port", str(port),
                             "--log-level", "warning", *extra], env=env, cwd=REPO,
                            stdout=open(log, "wb"), stderr=subprocess.STDOUT, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(base + "/healthz", timeout=1).status_code == 200:
                return proc, base
        time.sleep(0.2)
    stop(proc)
    raise RuntimeError("server did not start:\n" + log.read_text()[-2000:])


def stop(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        pass
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(5)


def proc_kb(pid: int, field: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise KeyError(field)


def reset_peak(pid: int) -> bool:
    """Reset VmHWM to the current RSS (Linux: write 5 to clear_refs); False if not allowed."""
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far."""
    f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def upload(base: str, path: Path, spec: dict) -> tuple[int, float, str]:
    """POST the survey with curl when present (a C client: the figure is the server's), else httpx."""
    t0 = time.perf_counter()
    if shutil.which("curl"):
        r = subprocess.run(["curl", "-s", "-w", "\n%{http_code}", "-F", f"survey=@{path}",
                            "-F", f"spec={json.dumps(spec)}", base + "/reconstructions"],
                           capture_output=True, text=True, timeout=600, check=False)
        body, _, code = r.stdout.rpartition("\n")
        return int(code or 0), time.perf_counter() - t0, body[:200]
    with open(path, "rb") as fh:
        resp = httpx.post(base + "/reconstructions", files={"survey": (path.name, fh, "application/x-hdf5")},
                          data={"spec": json.dumps(spec)}, timeout=600)
    return resp.status_code, time.perf_counter() - t0, resp.text[:200]


def bench_upload(tmp: Path, gigabytes: float) -> None:
    survey = tmp / "big.h5"
    t0 = time.perf_counter()
    size = write_big_survey(survey, gigabytes)
    print(f"upload: survey {size / 1e6:.0f} MB written in {time.perf_counter() - t0:.1f} s; "
          f"client: {'curl' if shutil.which('curl') else 'httpx'}")
    proc, base = start_server(tmp / "data-upload", tmp / "upload.log", "--no-worker")
    try:
        time.sleep(1.0)
        rss0 = proc_kb(proc.pid, "VmRSS")
        exact = reset_peak(proc.pid)
        c0 = cpu_s(proc.pid)
        status, dt, text = upload(base, survey, {"grid": 100000})  # refused after the full upload
        hwm = proc_kb(proc.pid, "VmHWM")
        print(f"upload only (spec refused after body stored): HTTP {status} in {dt:.2f} s = "
              f"{size / 1e6 / dt:.0f} MB/s; API CPU {cpu_s(proc.pid) - c0:.1f} s; "
              f"API peak RSS growth {(hwm - rss0) / 1024:.1f} MB "
              f"(RSS before {rss0 / 1024:.0f} MB{'' if exact else ', peak not resettable: upper bound'})")
        rss0 = proc_kb(proc.pid, "VmRSS")
        reset_peak(proc.pid)
        status, dt, text = upload(base, survey, {"methods": ["backprojection"], "grid": 16})
        hwm = proc_kb(proc.pid, "VmHWM")
        print(f"upload + validation to 202: HTTP {status} in {dt:.2f} s = {size / 1e6 / dt:.0f} MB/s; "
              f"API peak RSS growth {(hwm - rss0) / 1024:.1f} MB")
        if status != 202:
            print("  response:", text)
    finally:
        stop(proc)
        survey.unlink(missing_ok=True)


async def _get(reader: asyncio.StreamReader, writer: asyncio.StreamWriter, request: bytes) -> int:
    """One keep-alive HTTP/1.1 GET on an open connection; returns the status code."""
    writer.write(request)
    await writer.drain()
    head = await reader.readuntil(b"\r\n\r\n")
    status = int(head[9:12])
    length = 0
    for line in head.split(b"\r\n"):
        if line[:15].lower() == b"content-length:":
            length = int(line[15:])
    if length:
        await reader.readexactly(length)
    return status


async def poll_clients(base: str, job_id: str, clients: int, seconds: float, interval: float) -> list[float]:
    """``clients`` connections, each polling the job's status. A minimal raw HTTP/1.1 client:
    httpx's async pool costs ~4 ms of client CPU per request at this concurrency, which would
    measure the client, not the server."""
    host, port = base.removeprefix("http://").split(":")
    request = f"GET /reconstructions/{job_id} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()
    lat: list[float] = []
    errors = 0
    end = time.perf_counter() + seconds

    async def one(k: int) -> None:
        nonlocal errors
        reader, writer = await asyncio.open_connection(host, int(port))
        await asyncio.sleep(interval * k / clients if interval else 0)  # spread the phases
        try:
            while time.perf_counter() < end:
                t = time.perf_counter()
                try:
                    if await _get(reader, writer, request) != 200:
                        errors += 1
                except (OSError, asyncio.IncompleteReadError, ValueError):
                    errors += 1
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, int(port))
                dt = time.perf_counter() - t
                lat.append(dt)
                if interval:
                    await asyncio.sleep(max(0.0, interval - dt))
        finally:
            writer.close()

    await asyncio.gather(*(one(k) for k in range(clients)))
    if errors:
        print(f"  errors: {errors}")
    return lat


async def poll_httpx(base: str, job_id: str, clients: int, seconds: float, interval: float) -> list[float]:
    """``clients`` pollers sharing one ``httpx.AsyncClient`` (a connection each), each sending one
    GET per ``interval`` on a fixed schedule, so a slow answer does not lower the offered load."""
    lat: list[float] = []
    errors = 0
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=base, limits=limits, timeout=60) as client:
        end = time.perf_counter() + seconds

        async def one(k: int) -> None:
            nonlocal errors
            due = time.perf_counter() + interval * k / clients  # spread the phases
            while True:
                await asyncio.sleep(max(0.0, due - time.perf_counter()))
                if time.perf_counter() >= end:
                    return
                t = time.perf_counter()
                try:
                    if (await client.get(f"/reconstructions/{job_id}")).status_code != 200:
                        errors += 1
                except httpx.HTTPError:
                    errors += 1
                lat.append(time.perf_counter() - t)
                due += interval

        await asyncio.gather(*(one(k) for k in range(clients)))
    if errors:
        print(f"  errors: {errors}")
    return lat


def proc_info(pid: int) -> str:
    """Niceness and thread count of a process (Linux /proc)."""
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return f"nice {int(stat[16])}, {int(stat[17])} threads"


def local_worker_pid(serve_pid: int) -> int | None:
    for task in Path(f"/proc/{serve_pid}/task").iterdir():
        for pid in (task / "children").read_text().split():
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return int(pid)
    return None


def report(label: str, lat: list[float], seconds: float) -> None:
    a = np.asarray(lat) * 1000
    print(f"{label}: {len(a)} requests in {seconds:.0f} s = {len(a) / seconds:.0f} req/s; "
          f"p50 {np.percentile(a, 50):.1f} ms, p99 {np.percentile(a, 99):.1f} ms, max {a.max():.1f} ms")


def bench_polling(tmp: Path, clients: int, seconds: float, interval: float, closed_loop: bool,
                  client: str = "httpx") -> None:
    sys.path.insert(0, str(REPO))
    from shsas_core.formats.hdf5 import write_survey
    from tests.conftest import make_survey

    survey = write_survey(make_survey(), tmp / "tiny.h5")
    proc, base = start_server(tmp / "data-poll", tmp / "poll.log")
    try:
        with open(survey, "rb") as fh:
            job = httpx.post(base + "/reconstructions", files={"survey": ("tiny.h5", fh)},
                             data={"spec": json.dumps(LONG_SPEC)}, timeout=60).json()
        deadline = time.monotonic() + 60
        while httpx.get(f"{base}/reconstructions/{job['id']}").json()["status"] != "running":
            if time.monotonic() > deadline:
                raise RuntimeError("job did not start")
            time.sleep(0.2)
        deadline = time.monotonic() + 300
        while httpx.get(f"{base}/reconstructions/{job['id']}").json()["progress"] <= 0:  # training, not importing
            if time.monotonic() > deadline:
                raise RuntimeError("job did not start training")
            time.sleep(0.5)
        worker = local_worker_pid(proc.pid)
        print(f"  API pid {proc.pid}: {proc_info(proc.pid)}; local worker pid {worker}: "
              f"{proc_info(worker) if worker else 'not found'} (SHSAS_WORKER_NICE="
              f"{os.environ.get('SHSAS_WORKER_NICE', 'default')})")
        if closed_loop:
            lat = asyncio.run(poll_clients(base, job["id"], clients, seconds, 0.0))
            report(f"polling, {clients} clients, closed loop (raw client), job running", lat, seconds)
        if interval:
            c_api, c_worker, c_self = cpu_s(proc.pid), cpu_s(worker) if worker else 0.0, cpu_s(os.getpid())
            p0 = httpx.get(f"{base}/reconstructions/{job['id']}").json()["progress"]
            poll = poll_httpx if client == "httpx" else poll_clients
            lat = asyncio.run(poll(base, job["id"], clients, seconds, interval))
            p1 = httpx.get(f"{base}/reconstructions/{job['id']}").json()["progress"]
            report(f"polling, {clients} clients ({client} client) each every {interval:g} s, job training", lat, seconds)
            print(f"  CPU over the paced run: API {cpu_s(proc.pid) - c_api:.1f} s, worker "
                  f"{(cpu_s(worker) - c_worker) if worker else float('nan'):.1f} s, client "
                  f"{cpu_s(os.getpid()) - c_self:.1f} s in {seconds:.0f} s; job progress {p0:.4f} -> {p1:.4f}")
        final = httpx.get(f"{base}/reconstructions/{job['id']}").json()
        print(f"  job still {final['status']} at progress {final['progress']:.3f} during the run")
        httpx.post(f"{base}/reconstructions/{job['id']}/cancel")
    finally:
        stop(proc)


# ---- soak: mixed hostile and valid traffic while a job trains ---------------------------------

def tree_bytes(*roots: Path) -> int:
    """Bytes of the regular files under ``roots`` (missing roots count 0)."""
    total = 0
    for root in roots:
        for dirpath, _, files in os.walk(root):
            for f in files:
                with contextlib.suppress(OSError):
                    total += os.lstat(os.path.join(dirpath, f)).st_size
    return total


def api_pids(serve_pid: int, worker: int | None) -> list[int]:
    """serve itself and its uvicorn worker processes (not the job worker, not helpers)."""
    pids = [serve_pid]
    for task in Path(f"/proc/{serve_pid}/task").iterdir():
        for pid in (task / "children").read_text().split():
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
            if int(pid) != worker and b"spawn_main" in cmd:
                pids.append(int(pid))
    return pids


def api_rss_mib(pids: list[int]) -> float:
    total = 0
    for pid in pids:
        with contextlib.suppress(OSError, KeyError):
            total += proc_kb(pid, "VmRSS")
    return total / 1024


class Tally:
    def __init__(self) -> None:
        self.status: dict[str, int] = {}
        self.server_errors = 0
        self.lat: list[float] = []

    def add(self, what: str, status: int) -> None:
        key = f"{what} {status}"
        self.status[key] = self.status.get(key, 0) + 1
        if status >= 500 and status != 503:
            self.server_errors += 1
        elif status == 503:  # allowed only as a refusal with Retry-After; counted apart
            self.status["503 (refusals)"] = self.status.get("503 (refusals)", 0) + 1


async def _raw(host: str, port: int, data: bytes, read_s: float = 120.0) -> int:
    """Send ``data`` on a fresh connection; the answer's status (0 if none before the close)."""
    try:
        reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 5)
    except (TimeoutError, OSError):
        return 0
    try:
        with contextlib.suppress(OSError):
            writer.write(data)
            await writer.drain()
        head = await asyncio.wait_for(reader.read(64), read_s)
        return int(head[9:12]) if head.startswith(b"HTTP/1.1 ") else 0
    except (TimeoutError, OSError, ValueError):
        return 0
    finally:
        writer.close()


async def _slowloris(host: str, port: int, n: int, seconds: float) -> int:
    """``n`` connections trickling a header byte a second for up to ``seconds``; how many the
    server cut off before the end."""
    conns = []
    for _ in range(n):
        with contextlib.suppress(OSError, asyncio.TimeoutError):
            conns.append(await asyncio.wait_for(asyncio.open_connection(host, port), 5))
    for _, w in conns:
        with contextlib.suppress(OSError):
            w.write(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
    end, cut = time.monotonic() + seconds, set()
    while time.monotonic() < end and len(cut) < len(conns):
        await asyncio.sleep(1.0)
        for i, (r, w) in enumerate(conns):
            if i in cut:
                continue
            if r.at_eof() or w.is_closing():
                cut.add(i)
                continue
            with contextlib.suppress(OSError):
                w.write(b"X")
    for _, w in conns:
        w.close()
    return len(cut)


async def hostile_loop(base: str, end: float, tally: Tally, survey: bytes, junk_zip: bytes) -> None:
    host, port_s = base.removeprefix("http://").split(":")
    port = int(port_s)
    rng = np.random.default_rng(1)

    def multipart(fields: list[tuple[str, str, bytes]], boundary: str = "soakb") -> bytes:
        out = b""
        for name, filename, data in fields:
            disp = f'form-data; name="{name}"' + (f'; filename="{filename}"' if filename else "")
            out += f"--{boundary}\r\nContent-Disposition: {disp}\r\n\r\n".encode() + data + b"\r\n"
        return out + f"--{boundary}--\r\n".encode()

    def post(body: bytes, length: int | None = None, extra: str = "") -> bytes:
        n = len(body) if length is None else length
        return (f"POST /reconstructions HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; "
                f"boundary=soakb\r\nContent-Length: {n}\r\n{extra}Connection: close\r\n\r\n").encode() + body

    spec = json.dumps({"methods": ["backprojection"], "grid": 16, "device": "cpu"}).encode()
    async with httpx.AsyncClient(base_url=base, timeout=120) as c:
        round_ = 0
        while time.monotonic() < end:
            round_ += 1
            cut = await _slowloris(host, port, 50, 20)
            tally.status["slowloris connections cut"] = tally.status.get("slowloris connections cut", 0) + cut
            tally.add("big header", await _raw(host, port, b"GET /healthz HTTP/1.1\r\nX: " + b"a" * 200_000 + b"\r\n\r\n"))
            tally.add("junk request line", await _raw(host, port, bytes(rng.integers(0, 256, 300, dtype=np.uint8)) + b"\r\n\r\n"))
            tally.add("non-survey", await _raw(host, port, post(multipart([("survey", "x.h5", rng.bytes(50_000)), ("spec", "", spec)]))))
            tally.add("junk zip", await _raw(host, port, post(multipart([("survey", "scan.zip", junk_zip), ("spec", "", spec)]))))
            # the body never completes: the server waits for it, the client gives up (status 0)
            tally.add("truncated body", await _raw(host, port, post(multipart([("survey", "x.h5", survey)])[:2000], length=len(survey) + 500), 10))
            tally.add("no spec", await _raw(host, port, post(multipart([("survey", "x.h5", survey)]))))
            tally.add("bad boundary", await _raw(host, port, post(b"--nope\r\n\r\n")))
            for method, path in (("GET", "/reconstructions/" + "f" * 32), ("HEAD", "/reconstructions/zz"),
                                 ("DELETE", "/reconstructions/" + "0" * 32), ("GET", "/reconstructions?cursor=%%%"),
                                 ("GET", "/reconstructions/x/artifacts/../../etc/passwd")):
                tally.add(f"{method} junk", (await c.request(method, path)).status_code)
            tally.add("bad key", (await c.get("/reconstructions", headers={"Authorization": "Bearer shsas_x_y"})).status_code)
            r = await c.post("/reconstructions", files={"survey": ("tiny.h5", survey)}, data={"spec": spec.decode()})
            tally.add("valid submit", r.status_code)
            if r.status_code == 202:
                jid = r.json()["id"]
                tally.add("cancel", (await c.post(f"/reconstructions/{jid}/cancel")).status_code)
                tally.add("delete", (await c.delete(f"/reconstructions/{jid}")).status_code)


async def soak_pollers(base: str, job_id: str, clients: int, end: float, interval: float, tally: Tally) -> None:
    host, port = base.removeprefix("http://").split(":")
    request = f"GET /reconstructions/{job_id} HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()

    async def one(k: int) -> None:
        reader, writer = await asyncio.open_connection(host, int(port))
        due = time.perf_counter() + interval * k / clients
        try:
            while time.monotonic() < end:
                await asyncio.sleep(max(0.0, due - time.perf_counter()))
                t = time.perf_counter()
                try:
                    status = await _get(reader, writer, request)
                except (OSError, asyncio.IncompleteReadError, ValueError):
                    status = 0  # closed (keep-alive timeout between polls): reconnect
                    writer.close()
                    reader, writer = await asyncio.open_connection(host, int(port))
                    status = await _get(reader, writer, request)
                tally.lat.append(time.perf_counter() - t)
                if status != 200:
                    tally.add("poll", status)
                due += interval
        finally:
            writer.close()

    await asyncio.gather(*(one(k) for k in range(clients)))


def bench_soak(tmp: Path, seconds: float, clients: int, interval: float, api_workers: int) -> None:
    import zipfile

    from shsas_core.formats.hdf5 import write_survey
    from tests.conftest import make_survey

    survey = write_survey(make_survey(), tmp / "tiny.h5")
    with zipfile.ZipFile(tmp / "junk.zip", "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("Coordinates.csv", "flight,x\n1,zz\n")
        z.writestr("zeros.bin", b"\0" * 50_000_000)  # compresses to ~50 kB
    server_tmp = tmp / "server-tmp"
    server_tmp.mkdir()
    data = tmp / "data-soak"
    proc, base = start_server(data, tmp / "soak.log", "--workers", str(api_workers),
                              env_extra={"TMPDIR": str(server_tmp)})
    try:
        with open(survey, "rb") as fh:
            job = httpx.post(base + "/reconstructions", files={"survey": ("tiny.h5", fh)},
                             data={"spec": json.dumps(LONG_SPEC)}, timeout=60).json()
        deadline = time.monotonic() + 300
        while httpx.get(f"{base}/reconstructions/{job['id']}").json()["progress"] <= 0:
            if time.monotonic() > deadline:
                raise RuntimeError("job did not start training")
            time.sleep(0.5)
        worker = local_worker_pid(proc.pid)
        pids = api_pids(proc.pid, worker)
        rss0, temp0 = api_rss_mib(pids), tree_bytes(server_tmp, data / "uploads")
        print(f"soak: {seconds:.0f} s, {clients} pollers every {interval:g} s + 1 hostile client, "
              f"{len(pids)} API process(es), job {job['id']} training; API RSS {rss0:.0f} MiB at start")
        tally = Tally()
        end = time.monotonic() + seconds

        async def both() -> None:
            await asyncio.gather(soak_pollers(base, job["id"], clients, end, interval, tally),
                                 hostile_loop(base, end, tally, survey.read_bytes(), (tmp / "junk.zip").read_bytes()))

        asyncio.run(both())
        time.sleep(5)  # let the last validations and sweeps finish
        rss1, temp1 = api_rss_mib(api_pids(proc.pid, worker)), tree_bytes(server_tmp, data / "uploads")
        a = np.asarray(tally.lat) * 1000
        final = httpx.get(f"{base}/reconstructions/{job['id']}").json()
        print(f"  5xx answers (not 503 refusals): {tally.server_errors}")
        print(f"  temp bytes left: {temp1 - temp0} (server TMPDIR + uploads/: {temp0} before, {temp1} after)")
        print(f"  API RSS: {rss0:.0f} -> {rss1:.0f} MiB (delta {rss1 - rss0:+.0f} MiB)")
        print(f"  status polls: {len(a)}, p50 {np.percentile(a, 50):.1f} ms, p99 {np.percentile(a, 99):.1f} ms, "
              f"max {a.max():.1f} ms")
        print(f"  job: {final['status']} at progress {final['progress']:.3f}")
        print("  answers: " + ", ".join(f"{k}: {v}" for k, v in sorted(tally.status.items())))
        httpx.post(f"{base}/reconstructions/{job['id']}/cancel")
    finally:
        stop(proc)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=30.0, help="polling duration per mode (max 120)")
    ap.add_argument("--clients", type=int, default=100)
    ap.add_argument("--interval", type=float, default=1.0, help="paced mode: seconds between a client's polls (0 = skip)")
    ap.add_argument("--closed-loop", type=int, default=1, help="1: also run the closed-loop polling (0 = skip)")
    ap.add_argument("--client", choices=["httpx", "raw"], default="httpx",
                    help="paced mode's client: httpx.AsyncClient, or the minimal raw HTTP/1.1 client "
                    "(~10x less client CPU per request, for machines where the client is the bottleneck)")
    ap.add_argument("--upload-gb", type=float, default=1.0, help="survey size for the upload test (0 = skip)")
    ap.add_argument("--soak", action="store_true", help="run the soak instead (see 3. above)")
    ap.add_argument("--soak-seconds", type=float, default=1800.0, help="soak duration (default 30 min)")
    ap.add_argument("--api-workers", type=int, default=1, help="soak: API processes (shsas serve --workers)")
    args = ap.parse_args()
    seconds = min(args.seconds, 120.0)
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start")
    with tempfile.TemporaryDirectory(prefix="shsas-bench-") as d:
        tmp = Path(d)
        if args.soak:
            bench_soak(tmp, args.soak_seconds, args.clients, args.interval or 1.0, args.api_workers)
            print(f"load average {os.getloadavg()[0]:.1f} at end")
            return
        if args.upload_gb > 0:
            bench_upload(tmp, args.upload_gb)
        bench_polling(tmp, args.clients, seconds, args.interval, bool(args.closed_loop), args.client)
    print(f"load average {os.getloadavg()[0]:.1f} at end")


if __name__ == "__main__":
    main()
