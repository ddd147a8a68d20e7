"""A small analytic scattering field with the SHField interface, for renderer/trainer tests.

|sigma_DC| is a Gaussian shell of radius ``radius`` around ``center`` (width ``width``), with a
phase linear in x; the scattering adds a first-order lobe ``beta (dirs . e)``. Normals come from
autograd of |sigma_DC| like the real field. Parameters are learnable so gradcheck can use them.
"""

from __future__ import annotations

import math

import torch

INV_SQRT_4PI = 1.0 / math.sqrt(4.0 * math.pi)


class ShellField(torch.nn.Module):
    def __init__(self, center=(0.0, 0.0, 0.1), radius=0.05, width=0.01, amp=5.0, beta=0.3,
                 zeta=1.0, dtype=torch.float64):
        super().__init__()
        self.center = torch.nn.Parameter(torch.tensor(center, dtype=dtype))
        self.radius = torch.nn.Parameter(torch.tensor(radius, dtype=dtype))
        self.log_amp = torch.nn.Parameter(torch.tensor(math.log(amp), dtype=dtype))
        self.beta = torch.nn.Parameter(torch.tensor(beta, dtype=dtype))
        self.kvec = torch.nn.Parameter(torch.tensor([30.0, -20.0, 10.0], dtype=dtype))
        self.width = width
        self.zeta = zeta
        self.register_buffer("lobe", torch.tensor([0.0, 0.0, 1.0], dtype=dtype))

    def dc_abs(self, x):
        rr = (x - self.center).norm(dim=-1)
        return torch.exp(self.log_amp) * torch.exp(-0.5 * ((rr - self.radius) / self.width) ** 2)

    def forward(self, x, dirs, with_normals=True, create_graph=None):
        if create_graph is None:
            create_graph = torch.is_grad_enabled()
        with torch.enable_grad():
            xg = x if x.requires_grad else x.detach().requires_grad_(True)
            mag = self.dc_abs(xg)
            phase = xg @ self.kvec
            dc = torch.polar(mag, phase)
            out = {"density": mag * self.zeta, "dc": dc,
                   "scattering": dc * (1.0 + self.beta * (dirs @ self.lobe)).to(dc.dtype)}
            if with_normals:
                (g,) = torch.autograd.grad(mag.sum(), xg, create_graph=create_graph, retain_graph=True)
                n = -g / g.norm(dim=-1, keepdim=True).clamp_min(1e-30)
                out["normals"] = n if create_graph else n.detach()
                out["gradient"] = g if create_graph else g.detach()
        if not torch.is_grad_enabled():
            out = {k: v.detach() for k, v in out.items()}
        return out
