"""The CPU hash-encoding kernel of ``hashgrid_cpu.c``: built on first use, called through ctypes.

Why a C kernel: the PyTorch fused path (:func:`.encoding.encode_fused`) materialises every
intermediate of the trilinear interpolation as a full ``(F, 8, P, L)`` tensor; on a CPU that
memory traffic is two thirds of a training iteration. The C kernel keeps the 8 corner values of
one (point, level) in registers and writes only the features, the Jacobian and the table
gradient. The maths is the same, and the tests compare it with the eager reference.

Building needs only a C compiler (``$CC``, else ``cc``/``gcc``/``clang``; no Python or torch
headers), takes about a second, and is cached per source, flags and machine type in
``$SHSAS_CACHE_DIR/native`` (default ``~/.cache/shsas``; a temporary directory when that is not
writable). A library found there is used without a compiler (a service image builds it once). Without a compiler, or when
the build fails, :func:`available` is False (with a one-time warning saying why) and the fused
PyTorch ops run instead, with identical results. ``SHSAS_NATIVE=0`` turns the kernel off.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
import threading
import warnings
from pathlib import Path

import torch

SOURCE = Path(__file__).with_name("hashgrid_cpu.c")
FLAGS = ("-O3", "-std=c11", "-fPIC", "-shared", "-pthread")

_lock = threading.Lock()
_state: dict[str, object] = {}


def _cache_dirs() -> list[Path]:
    """Where built libraries live: ``$SHSAS_CACHE_DIR`` (default ``~/.cache/shsas``), then a
    per-user temporary directory for when the first is not writable (a read-only home)."""
    base = os.environ.get("SHSAS_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "shsas")
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return [Path(base) / "native", Path(tempfile.gettempdir()) / f"shsas-native-{uid}"]


def _compiler() -> str | None:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def _compile(cc: str, directory: Path, name: str) -> Path:
    """Compile the source into ``directory / name``; OSError when the directory is not writable."""
    directory.mkdir(parents=True, exist_ok=True)
    # build beside the target and rename: concurrent processes never load a half-written file
    fd, tmp = tempfile.mkstemp(suffix=".so", dir=directory)
    os.close(fd)
    try:
        proc = subprocess.run([cc, *FLAGS, str(SOURCE), "-o", tmp, "-lm"], capture_output=True, text=True,
                              timeout=300)
        if proc.returncode != 0:
            raise RuntimeError(f"{Path(cc).name} failed: {proc.stderr.strip()[-300:]}")
        os.chmod(tmp, 0o755)  # mkstemp makes it 0600; other users of a shared cache may load it
        os.replace(tmp, directory / name)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return directory / name


def _build() -> ctypes.CDLL:
    """Compile (or reuse) the shared library and declare its functions. Raises on failure."""
    # the C ABI does not depend on the compiler, so the key is the source, flags and machine
    key = hashlib.sha256(SOURCE.read_bytes() + " ".join(FLAGS).encode()
                         + platform.machine().encode()).hexdigest()[:16]
    name = f"hashgrid-{key}.so"
    dirs = _cache_dirs()
    # a library built earlier (e.g. into an image at build time) is used even from a read-only
    # dir and without a compiler
    lib_path = next((d / name for d in dirs if (d / name).exists()), None)
    if lib_path is None:
        cc = _compiler()
        if cc is None:
            raise RuntimeError("no C compiler found (set CC, or install gcc)")
        errors = []
        for d in dirs:
            try:
                lib_path = _compile(cc, d, name)
                break
            except OSError as exc:  # not writable: try the next directory
                errors.append(f"{d}: {exc.strerror or exc}")
        if lib_path is None:
            raise RuntimeError("no writable cache directory (" + "; ".join(errors) + ")")
    lib = ctypes.CDLL(str(lib_path))
    i64, ptr = ctypes.c_int64, ctypes.c_void_p
    lib.shsas_hash_forward.argtypes = [i64, ptr, ptr, i64, i64, ptr, ptr, ptr, ptr, i64, ptr, ptr, i64]
    lib.shsas_hash_forward.restype = ctypes.c_int
    lib.shsas_hash_backward.argtypes = [i64, ptr, ptr, ptr, i64, i64, ptr, ptr, ptr, ptr, i64, i64, ptr,
                                        ptr, i64]
    lib.shsas_hash_backward.restype = ctypes.c_int
    lib.shsas_hash_threads.argtypes = [i64, i64]
    lib.shsas_hash_threads.restype = i64
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded kernel library, or None (disabled, or the build failed: warned once)."""
    if "lib" in _state:
        return _state["lib"]  # type: ignore[return-value]
    with _lock:
        if "lib" not in _state:
            lib = None
            if os.environ.get("SHSAS_NATIVE", "1") not in ("0", "false", "no"):
                try:
                    lib = _build()
                except Exception as exc:  # never fail a job over an optional speed-up
                    _state["error"] = str(exc)
                    warnings.warn(f"hash encoding: the C kernel is unavailable ({exc}); using PyTorch ops",
                                  RuntimeWarning, stacklevel=3)
            _state["lib"] = lib
    return _state["lib"]  # type: ignore[return-value]


def available() -> bool:
    """Whether the C kernel can be used in this process."""
    return library() is not None


def usable(u: torch.Tensor, table: torch.Tensor) -> bool:
    """The kernel handles float32 CPU tensors; anything else takes the PyTorch path."""
    return (u.device.type == "cpu" and table.device.type == "cpu" and u.dtype == torch.float32
            and table.dtype == torch.float32 and available())


class NativeLayout:
    """The level arrays in the dtypes the kernel reads (built once per :class:`FusedLayout`)."""

    def __init__(self, res: torch.Tensor, mult: torch.Tensor, offsets: torch.Tensor, n_dense: int, mask: int):
        n = res.shape[0]
        self.n_levels = n
        self.res = res.detach().to("cpu", torch.float32).contiguous()
        self.mult = mult.detach().to("cpu", torch.int64).contiguous()
        self.offsets = offsets.detach().to("cpu", torch.int64).contiguous()
        self.dense = torch.tensor([1 if i < n_dense else 0 for i in range(n)], dtype=torch.uint8)
        self.mask = int(mask)


def _p(t: torch.Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


def forward(u: torch.Tensor, table: torch.Tensor, nl: NativeLayout,
            with_jacobian: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Features (P, L*F) and, with ``with_jacobian``, the Jacobian (3, P, L*F) (else empty).

    u: (P, 3) float32 in [0, 1]^3 (clamped by the caller); table: (N, F) float32.
    """
    lib = library()
    assert lib is not None
    u = u.contiguous()
    table = table.detach().contiguous()
    p, feat = u.shape[0], table.shape[1]
    out = torch.empty((p, nl.n_levels * feat), dtype=torch.float32)
    jac = torch.empty((3, p, nl.n_levels * feat), dtype=torch.float32) if with_jacobian else None
    lib.shsas_hash_forward(p, _p(u), _p(table), nl.n_levels, feat, _p(nl.res), _p(nl.mult), _p(nl.offsets),
                           _p(nl.dense), nl.mask, _p(out), _p(jac), torch.get_num_threads())
    return out, (jac if jac is not None else out.new_zeros(0))


def backward(u: torch.Tensor, g_out: torch.Tensor, g_jac: torch.Tensor | None, nl: NativeLayout,
             n_rows: int, n_features: int) -> torch.Tensor:
    """Table gradient (N, F) from the gradients of the features (P, L*F) and Jacobian (3, P, L*F)."""
    lib = library()
    assert lib is not None
    u = u.contiguous()
    g_out = g_out.to(torch.float32).contiguous()
    g_jac = None if g_jac is None else g_jac.to(torch.float32).contiguous()
    p = u.shape[0]
    threads = int(lib.shsas_hash_threads(torch.get_num_threads(), p))
    if p * nl.n_levels * 8 < 4 * n_rows:
        # each extra thread costs a zeroed private table and its reduction (O(rows)); with fewer
        # than ~4 corner updates per row that is more than the scatter it takes over (measured:
        # 4,096 points on the cpu preset, 2.0 ms on one thread and 2.9 ms on two)
        threads = 1
    g_tab = torch.zeros((n_rows, n_features), dtype=torch.float32)
    privates = [torch.zeros((n_rows, n_features), dtype=torch.float32) for _ in range(threads - 1)]
    ptrs = (ctypes.c_void_p * max(len(privates), 1))(*[t.data_ptr() for t in privates])
    lib.shsas_hash_backward(p, _p(u), _p(g_out), _p(g_jac), nl.n_levels, n_features, _p(nl.res), _p(nl.mult),
                            _p(nl.offsets), _p(nl.dense), nl.mask, n_rows, _p(g_tab), ptrs, threads)
    return g_tab
