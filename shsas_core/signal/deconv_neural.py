"""Neural pulse deconvolution (Reed et al. 2023; SH-SAS paper §3.1).

For each batch of pings an implicit network ``N_PD(t, ping)`` — a 2-D multi-resolution hash
encoding over (time, ping) followed by a small ReLU MLP with a complex (2-channel) output — is
fit so that its output convolved with the analytic pulse reproduces the analytic measurement:

``L = mean |N ⊛ p_a - s|² + λ1 mean |N| + λ2 mean |Δ_t ∠N|``

(all means over the batch's samples; the measurement is scaled to unit peak per batch and the
result scaled back, so λ1 and λ2 do not depend on the data's units). ``s_PD = N`` on the
survey's own sample times. The encoding's finest level has one cell per sample along time and
one per ping, so the network can place an impulse at any sample; the coarse levels and the MLP
couple neighbouring samples and pings, which is the implicit prior of the method.

The sample positions are the same at every step, so the hash indices and bilinear weights are
computed once per batch and each step is gathers, one small MLP and two FFTs.
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Iterator

import numpy as np
import torch
from torch import nn

from shsas_core.common.optim import adam
from shsas_core.common.progress import ProgressFn, StopFn, check_stop, no_progress

_PRIME = 2654435761  # spatial-hash prime of Instant-NGP for the second axis


class HashGrid2D(nn.Module):
    """Multi-resolution 2-D hash encoding over (time, ping) with per-axis resolutions.

    Level ``l`` has ``res_t[l]`` x ``res_p[l]`` cells; when its vertex count exceeds the table
    size, vertices are hashed (``x ^ y·prime mod size``), otherwise indexed densely.

    Args:
        res_t, res_p: cells per level along time and ping.
        features: features per level. log2_size: table entries per level = 2^log2_size.
    """

    def __init__(self, res_t: list[int], res_p: list[int], features: int, log2_size: int):
        super().__init__()
        self.res_t, self.res_p = list(res_t), list(res_p)
        self.features = features
        cap = 1 << log2_size
        # Each level's table holds min(vertices, 2^log2_size) rows: coarse levels stay dense
        # and small, which keeps the parameter count (and Adam's work per step) low.
        self.sizes = [min(cap, (rt + 1) * (rp + 1)) for rt, rp in zip(res_t, res_p, strict=True)]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)[:-1]]).astype(int).tolist()
        self.tables = nn.Parameter(torch.empty(sum(self.sizes), features).uniform_(-1e-4, 1e-4))

    @property
    def out_dim(self) -> int:
        return len(self.res_t) * self.features

    def lookup(self, u: torch.Tensor, v: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat table indices (L, M, 4) int64 and bilinear weights (L, M, 4) for u, v in [0, 1]."""
        idx, wts = [], []
        for lvl, (rt, rp) in enumerate(zip(self.res_t, self.res_p, strict=True)):
            size = self.sizes[lvl]
            x, y = u * rt, v * rp
            x0 = torch.floor(x).clamp(0, max(rt - 1, 0))
            y0 = torch.floor(y).clamp(0, max(rp - 1, 0))
            fx, fy = x - x0, y - y0
            x0l, y0l = x0.long(), y0.long()
            corners, weights = [], []
            for dx in (0, 1):
                for dy in (0, 1):
                    xi, yi = x0l + dx, y0l + dy
                    if (rt + 1) * (rp + 1) <= size:
                        h = xi * (rp + 1) + yi
                    else:
                        h = (xi ^ (yi * _PRIME)) % size
                    corners.append(h + self.offsets[lvl])
                    weights.append((fx if dx else 1 - fx) * (fy if dy else 1 - fy))
            idx.append(torch.stack(corners, -1))
            wts.append(torch.stack(weights, -1))
        return torch.stack(idx), torch.stack(wts)

    def forward_lookup(self, idx: torch.Tensor, wts: torch.Tensor) -> torch.Tensor:
        """Features (M, L·F) from precomputed :meth:`lookup` results."""
        feats = (self.tables[idx] * wts[..., None]).sum(2)  # (L, M, F)
        return feats.permute(1, 0, 2).reshape(idx.shape[1], -1)


class DeconvNet(nn.Module):
    """Hash encoding + ReLU MLP -> complex value per (time, ping) sample."""

    def __init__(self, res_t: list[int], res_p: list[int], features: int, log2_size: int,
                 hidden: int, layers: int):
        super().__init__()
        self.encoding = HashGrid2D(res_t, res_p, features, log2_size)
        dims = [self.encoding.out_dim] + [hidden] * layers
        mods: list[nn.Module] = []
        for a, b in itertools.pairwise(dims):
            mods += [nn.Linear(a, b), nn.ReLU()]
        out = nn.Linear(dims[-1], 2)
        nn.init.normal_(out.weight, std=1e-3)
        nn.init.zeros_(out.bias)
        self.mlp = nn.Sequential(*mods, out)

    def forward(self, idx: torch.Tensor, wts: torch.Tensor) -> torch.Tensor:
        y = self.mlp(self.encoding.forward_lookup(idx, wts))
        return torch.complex(y[:, 0], y[:, 1])


def level_resolutions(t: int, b: int, levels: int, base: int) -> tuple[list[int], list[int]]:
    """Per-level cell counts: time from ``base`` up to ``t - 1`` (one cell per sample) in a
    geometric progression; pings likewise up to ``b - 1`` (at least 1)."""
    top_t = max(t - 1, 1)
    base = min(base, top_t)
    g = (top_t / base) ** (1 / max(levels - 1, 1))
    res_t = [max(1, round(base * g**i)) for i in range(levels)]
    res_t[-1] = top_t
    top_p = max(b - 1, 1)
    res_p = [max(1, min(top_p, round(top_p * r / top_t))) for r in res_t]
    res_p[-1] = top_p
    return res_t, res_p


def phase_gradient_l1(y: torch.Tensor, floor: float) -> torch.Tensor:
    """Mean |wrapped phase difference| between neighbouring samples of (B, T) complex ``y``.

    Where either sample is below ``floor`` in magnitude the phase is undefined and the term is 0
    (the double-``where`` keeps atan2's gradient finite there).
    """
    q = y[:, 1:] * torch.conj(y[:, :-1])
    ok = q.abs() > floor * floor
    safe = torch.where(ok, q, torch.ones_like(q))
    dphi = torch.atan2(safe.imag, safe.real)
    return torch.where(ok, dphi.abs(), torch.zeros_like(dphi)).mean()


def fit_batch(
    s: torch.Tensor,
    replica_spec: torch.Tensor,
    nfft: int,
    cfg,
    progress: ProgressFn = no_progress,
    should_stop: StopFn | None = None,
    carrier: torch.Tensor | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Fit one network to a batch of pings.

    Args:
        s: (B, T) complex64 measurement scaled to unit peak.
        replica_spec: (nfft,) complex FFT of the analytic replica.
        nfft: FFT length >= T + P - 1 (linear convolution).
        cfg: :class:`~shsas_core.signal.deconv.NeuralDeconvConfig`.
        carrier: (T,) complex ``exp(j2π f_b k / fs)`` at the band centre ``f_b``: the network
            models the slowly varying envelope and ``s_PD = envelope · carrier``. Without it a
            ReLU MLP on a hash grid, whose outputs are smooth, put ~90 % of its energy below the
            pulse band on a simulated sphere, where the data cannot see (or correct) it.
    Returns:
        ((B, T) complex64 s_PD, final loss terms).
    """
    b, t = s.shape
    dev = s.device
    gen = torch.Generator().manual_seed(cfg.seed)
    res_t, res_p = level_resolutions(t, b, cfg.levels, cfg.base_resolution)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(torch.randint(0, 2**31 - 1, (1,), generator=gen)))
        net = DeconvNet(res_t, res_p, cfg.features_per_level, cfg.log2_table_size,
                        cfg.hidden, cfg.layers).to(dev)
    u = (torch.arange(t, device=dev, dtype=torch.float32) / max(t - 1, 1)).repeat(b)
    v = (torch.arange(b, device=dev, dtype=torch.float32) / max(b - 1, 1)).repeat_interleave(t)
    with torch.no_grad():
        idx, wts = net.encoding.lookup(u, v)
    opt = adam(net.parameters(), lr=cfg.lr)
    floor = 1e-4
    terms: dict[str, float] = {}
    report = max(1, cfg.steps // 50)
    for step in range(cfg.steps):
        if step % report == 0:
            check_stop(should_stop)
        env = net(idx, wts).reshape(b, t)
        y = env if carrier is None else env * carrier
        pred = torch.fft.ifft(torch.fft.fft(y, nfft, dim=-1) * replica_spec, dim=-1)[:, :t]
        data = (pred - s).abs().pow(2).mean()
        sparse = env.abs().mean()
        # phase smoothness of the envelope: the carrier's constant phase step is not penalised
        phase = phase_gradient_l1(env, floor) if cfg.lambda_phase > 0 else env.new_zeros((), dtype=torch.float32)
        loss = data + cfg.lambda_sparsity * sparse + cfg.lambda_phase * phase
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if step % report == 0 or step == cfg.steps - 1:
            terms = {"loss": loss.item(), "data": data.item(), "l1": sparse.item(), "phase": phase.item()}
            progress((step + 1) / cfg.steps, "deconvolution", terms)
    with torch.no_grad():
        y = net(idx, wts).reshape(b, t)
        if carrier is not None:
            y = y * carrier
    return y.detach(), terms


@contextlib.contextmanager
def _cpu_threads_for(points: int, device: torch.device) -> Iterator[None]:
    """Run small CPU fits on one thread.

    A batch of a few thousand samples makes every op a few microseconds long; OpenMP's fork/join
    then costs more than it saves, and on a loaded machine (more busy threads than cores) each
    barrier waits for a descheduled thread: measured 9 ms/step on 1 thread vs 80-200 ms/step on
    2 threads for 2 x 500 samples on a shared 2-core box. The setting is restored afterwards.
    """
    if device.type != "cpu" or points >= 200_000 or torch.get_num_threads() == 1:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def neural_deconvolve(
    signals: np.ndarray,
    replica: np.ndarray,
    cfg,
    device: torch.device | str = "cpu",
    progress: ProgressFn = no_progress,
    should_stop: StopFn | None = None,
    band_centre: float = 0.0,
) -> np.ndarray:
    """Neural deconvolution of all pings, batch by batch.

    Args:
        signals: (N, T) complex analytic (or baseband) samples.
        replica: (P,) complex replica in the same frame, starting at lag 0.
        cfg: :class:`~shsas_core.signal.deconv.NeuralDeconvConfig`.
        band_centre: centre of the pulse band in the signals' frame as a fraction of fs
            (``f_b / fs``); the network models the envelope around it (see :func:`fit_batch`).
    Returns:
        (N, T) complex64 s_PD in the units of ``signals`` (an echo ``A p_a(t - τ)`` -> ``≈ A δ``).
    """
    dev = torch.device(device)
    n, t = signals.shape
    nfft = int(2 ** math.ceil(math.log2(t + replica.size - 1)))
    rep = torch.fft.fft(torch.as_tensor(replica, dtype=torch.complex64, device=dev), nfft)
    out = np.zeros((n, t), np.complex64)
    k = torch.arange(t, device=dev, dtype=torch.float64)
    carrier = torch.exp(2j * math.pi * band_centre * k).to(torch.complex64) if band_centre else None
    nb = cfg.pings_per_batch
    batches = [(a, min(a + nb, n)) for a in range(0, n, nb)]
    for i, (a, bnd) in enumerate(batches):
        check_stop(should_stop)
        s = torch.as_tensor(np.asarray(signals[a:bnd]), dtype=torch.complex64, device=dev)
        scale = float(s.abs().max())
        if scale == 0:
            continue

        def sub(f: float, stage: str, m, i=i) -> None:
            progress((i + f) / len(batches), stage, m)

        with _cpu_threads_for(s.numel(), dev):
            y, _ = fit_batch(s / scale, rep, nfft, cfg, sub, should_stop, carrier)
        out[a:bnd] = (y * scale).cpu().numpy()
    progress(1.0, "deconvolution", {})
    return out
