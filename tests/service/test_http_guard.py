"""Connection hygiene of a real `shsas serve` over real sockets on the loopback: a head too big
is 431, a head too slow is closed, a flood of trickling connections from one address leaves a
fresh client from another address served, and `--workers 2` runs two API processes that end
with serve. Every loop here is bounded in count and in time."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import time
from pathlib import Path

import httpx
import pytest

from .conftest import start_server

pytestmark = pytest.mark.service

#: A client address on the loopback other than the attackers' 127.0.0.1 (Linux routes 127/8 there).
FRESH_CLIENT = "127.0.0.2"


def _port(base: str) -> int:
    return int(base.rsplit(":", 1)[1])


def _status(sock: socket.socket, limit_s: float) -> int | None:
    """The status code of the first answer on ``sock`` within ``limit_s``; None if it closed
    without one or said nothing in time."""
    sock.settimeout(limit_s)
    try:
        head = sock.recv(4096)
    except (TimeoutError, ConnectionResetError):
        return None
    return int(head.split(b" ", 2)[1]) if head.startswith(b"HTTP/1.1 ") else None


@pytest.fixture(scope="module")
def guarded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("http_guard")
    env = {"SHSAS_DATA_DIR": str(tmp / "data"), "SHSAS_HTTP_HEADER_TIMEOUT_S": "2",
           "SHSAS_HTTP_MAX_CONNECTIONS_PER_CLIENT": "50"}
    # A descriptor limit of 256 scales the real attack (20,000 connections against the default
    # limit) down to a few hundred sockets.
    proc, base = start_server(tmp, env, name="guarded", wrap=("prlimit", "--nofile=256:256"))
    yield base
    proc.stop()


def test_a_head_over_the_cap_is_431_before_it_is_buffered(guarded) -> None:
    with socket.create_connection(("127.0.0.1", _port(guarded)), timeout=10) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Big: ")
        with contextlib.suppress(OSError):  # the server closes while we still send
            for _ in range(64):  # 4 MiB at most
                s.sendall(b"a" * 65536)
        assert _status(s, 10) == 431
    assert httpx.get(guarded + "/healthz", headers={"X-Fine": "a" * 8000}).status_code == 200


def test_a_trickled_head_is_closed_after_the_header_timeout(guarded) -> None:
    with socket.create_connection(("127.0.0.1", _port(guarded)), timeout=10) as s:
        s.sendall(b"GET /healthz HTTP/1.1\r\n")
        t0, answer = time.monotonic(), b""
        s.settimeout(0.5)
        while time.monotonic() - t0 < 20:  # one header byte every 0.5 s, for 20 s at most
            try:
                s.sendall(b"X")
                answer = s.recv(4096)
                break  # an answer, or b"" when closed
            except TimeoutError:
                continue
            except OSError:
                break
        assert time.monotonic() - t0 < 20, "the slow head was never cut off"
        assert answer.startswith(b"HTTP/1.1 408") or answer == b""


def test_trickling_flood_from_one_address_leaves_fresh_clients_served(guarded) -> None:
    socks: list[socket.socket] = []
    try:
        for _ in range(300):  # more than the 256 descriptors the server may hold
            try:
                s = socket.create_connection(("127.0.0.1", _port(guarded)), timeout=5)
                s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")  # and never finish the head
                socks.append(s)
            except OSError:
                break
        with httpx.Client(transport=httpx.HTTPTransport(local_address=FRESH_CLIENT), timeout=10) as c:
            assert c.get(guarded + "/healthz").status_code == 200
        # Past the per-address cap the attacker's own extra connections were refused with 503.
        refused = sum(_status(s, 0.2) == 503 for s in socks[60:80])
        assert refused > 0
    finally:
        for s in socks:
            s.close()


def _children(pid: int) -> set[int]:
    kids: set[int] = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            kids |= {int(p) for p in (task / "children").read_text().split()}
    return kids


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ", 1)[1][0] != "Z"
    except OSError:
        return False


@pytest.mark.slow
def test_two_api_processes_share_the_port_and_end_with_serve(tmp_path) -> None:
    env = {"SHSAS_DATA_DIR": str(tmp_path / "data")}
    proc, base = start_server(tmp_path, env, name="workers", args=("--workers", "2"))
    try:
        deadline = time.monotonic() + 120
        while len(_children(proc.pid)) < 3 and time.monotonic() < deadline:
            time.sleep(0.5)  # two uvicorn workers and the embedded job worker
        kids = _children(proc.pid)
        assert len(kids) >= 3, kids
        base_nice = os.getpriority(os.PRIO_PROCESS, proc.pid)
        nice = {pid: os.getpriority(os.PRIO_PROCESS, pid) for pid in kids}
        # the API processes keep serve's priority; the job worker lowers its own (SHSAS_WORKER_NICE)
        assert list(nice.values()).count(base_nice) >= 2 and max(nice.values()) >= max(base_nice, 10), nice
        assert all(httpx.get(base + "/healthz").status_code == 200 for _ in range(10))
        os.kill(proc.pid, signal.SIGKILL)
        deadline = time.monotonic() + 120  # a child still importing stops once it gets to run
        while any(_alive(k) for k in kids) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not any(_alive(k) for k in kids), "an API or worker process outlived serve"
    finally:
        proc.stop()
