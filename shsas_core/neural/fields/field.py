"""The SH-SAS neural scattering field (paper §4.1–4.3).

``x`` (P, 3) world metres -> ``u = (x - box.min) / box.size`` in [0,1]^3 -> hash encoding ->
MLP (``layers`` hidden layers of ``hidden`` units, ReLU) -> 2 (L+1)^2 outputs: the real parts
then the imaginary parts of the complex SH coefficients c_lm(x) (column ``l^2 + l + m``, see
:mod:`shsas_core.neural.fields.sh`). From them:

* scattering ``σ(x, ω) = Σ_lm c_lm(x) Y_lm(ω)``, ω the unit direction from the receiver to x;
* ``σ_DC(x) = c_00(x) / √(4π)`` and density ``ρ(x) = |σ_DC(x)| ζ`` (1/m along a path);
* normal ``n(x) = -∇|σ_DC| / ‖∇|σ_DC|‖`` (world frame; the zero vector where the gradient is 0).

Points outside the scene box (and non-finite points) have all coefficients set to 0, hence
density 0, scattering 0 and normal 0: the scene is empty outside the box (and the encoding is
never read out of range).

``FieldConfig.directional_scale`` (default 0.1) multiplies the degree >= 1 columns of the MLP's
output. The function class is unchanged: the weights can grow to compensate. What changes is
the step size. Adam moves every weight by about ``lr`` per step whatever its gradient, so with
plain outputs the 2((L+1)^2 - 1) directional coefficients grew as fast as the DC one. On the
simulated bunny at lr 3e-3 (L = 3), a few steps made some views 10–30x too bright, and the data
term's answer killed every unit of the second hidden layer. The field was then a constant, with
zero normals and no gradient. That happened on 2 of 3 seeds; with the factor, none of the 3
collapsed (docs/neural.md). L = 0 is unaffected.

**The hidden biases at initialisation** (:data:`HIDDEN_BIAS_INIT`). The table starts within
±1e-4, so at initialisation a hidden unit's input is almost exactly its bias. torch's default
(the product's) draws the biases uniformly in ±1/√fan_in: each first-layer unit with a negative
bias is then off at every point, gets no gradient, and stays off unless the table grows enough
to turn it on, so how many units a fit has is a draw of the seed. A zero or positive constant
bias leaves no first-layer unit off; the constants measured so far (zero, 0.1, 0.05) and why
none is the default are in docs/decisions/zero-hidden-biases.md.

``SHField.set_active_levels(a)`` weights hash level ``l`` by ``(1 - cos(π clamp(a - l, 0, 1))) / 2``
(BARF's window, Lin et al. 2021): levels below ``a`` count fully, the next one partly, finer ones
not at all. The trainer moves ``a`` up over the first iterations (``TrainConfig.coarse_to_fine``),
so the field settles its coarse shape before the fine, more collided levels can add speckle.

``FieldConfig.backend`` picks the implementation, with identical maths:

* ``reference``: Python-loop encoding; normals by ``torch.autograd.grad`` of
  ``|σ_DC|`` w.r.t. x (``create_graph=True`` when training, i.e. double backward).
* ``fused``: batched encoding (one gather for all levels) that also returns the analytic
  Jacobian d features / d u from the same corner values; the Jacobian is contracted with
  d|c_00| / d features from one reverse pass through the MLP (the forward's ReLU masks, one
  extra small matmul per layer). The normal is then an ordinary differentiable function of the
  parameters: training needs one first-order backward instead of a double backward, and the
  encoding is evaluated once per forward.
* ``native`` (the default): ``fused``, with the encoding's forward and first-order backward in
  the device's own kernel (one pass per point and level, the corner values in registers): on a
  CPU with float32 the C kernel of :mod:`.native`, built on first use; on CUDA the Triton
  kernels of :mod:`.encoding_triton` when Triton imports; the PyTorch fused ops otherwise.
  Same values.
* ``triton``: ``fused`` with the Triton kernels always (CUDA; CPU tensors only under Triton's
  interpreter, ``TRITON_INTERPRET=1``, which is how the tests run them without a GPU).
* ``compiled``: the fused encoding kernels through ``torch.compile`` (measured on
  a 2-core CPU: 20–60 s to compile, then no faster than the fused eager kernels; off by default).
"""

from __future__ import annotations

import itertools
import math

import torch

from shsas_core.common.errors import ShsasError
from shsas_core.neural.fields.base import device_dtype
from shsas_core.neural.fields.config import FieldConfig
from shsas_core.neural.fields.encoding import (
    HashEncoding,
)
from shsas_core.neural.fields.sh import sh_basis

INV_SQRT_4PI = 1.0 / math.sqrt(4.0 * math.pi)

#: The hidden layers' biases at initialisation (module doc): None, torch's default draw (uniform
#: in ±1/√fan_in); a number, that constant. The weights are drawn the same either way.
HIDDEN_BIAS_INIT: float | None = None


def level_window(n_levels: int, n_features: int, active: float) -> torch.Tensor:
    """Per-feature weights (n_levels * n_features,) of the level-major encoding for ``active``
    levels (module doc): 1 for levels l <= active - 1, 0 for l >= active, a cosine between."""
    t = (active - torch.arange(n_levels, dtype=torch.float64)).clamp(0.0, 1.0)
    return ((1.0 - torch.cos(math.pi * t)) / 2.0).repeat_interleave(n_features)


def _safe_abs(re: torch.Tensor, im: torch.Tensor) -> torch.Tensor:
    """|re + i im| with a zero (not NaN) gradient at 0, differentiable twice."""
    r2 = re * re + im * im
    ok = r2 > 0
    return torch.where(ok, torch.sqrt(torch.where(ok, r2, torch.ones_like(r2))), torch.zeros_like(r2))


def safe_normalize(v: torch.Tensor, eps: float = 1e-20) -> torch.Tensor:
    """v / ‖v‖ along the last axis; 0 where ‖v‖² <= eps (finite gradients everywhere)."""
    n2 = (v * v).sum(-1, keepdim=True)
    ok = n2 > eps
    inv = torch.where(ok, torch.rsqrt(torch.where(ok, n2, torch.ones_like(n2))), torch.zeros_like(n2))
    return v * inv


def normals_by_autograd(
    fn, x: torch.Tensor, create_graph: bool = False
) -> torch.Tensor:
    """-∇f / ‖∇f‖ at x by autograd, for a scalar-per-point function f: (P,3) -> (P,).

    The helper :meth:`SHField.normals` uses with ``f = |σ_DC|``. Works under ``torch.no_grad``
    (grad is enabled locally); with ``create_graph`` the normals stay differentiable.
    """
    with torch.enable_grad():
        xg = x if x.requires_grad else x.detach().requires_grad_(True)
        val = fn(xg)
        if not val.requires_grad:  # constant field: zero gradient everywhere
            return torch.zeros_like(x)
        (g,) = torch.autograd.grad(val.sum(), xg, create_graph=create_graph)
    n = -safe_normalize(g)
    return n if create_graph else n.detach()


class SHField(torch.nn.Module):
    """Neural field of complex SH scattering coefficients (see module docstring).

    Args:
        cfg: :class:`FieldConfig` (default CPU config, L = 3).
    """

    def __init__(self, cfg: FieldConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or FieldConfig()
        self.degree = cfg.sh_degree
        self.k = cfg.num_coefficients
        self.encoding = HashEncoding(cfg.encoding, backend=cfg.backend)
        dims = [self.encoding.output_dim] + [cfg.hidden] * cfg.layers + [2 * self.k]
        self.linears = torch.nn.ModuleList(torch.nn.Linear(a, b) for a, b in itertools.pairwise(dims))
        last = self.linears[-1]
        with torch.no_grad():
            # Small outputs: the table starts near 0 (±1e-4), so the output is ~ the last bias.
            # Re c_00 gets the bias giving density init_density; the rest start near 0 so the
            # initial scattering is almost isotropic and weak.
            last.weight.mul_(0.1)
            if HIDDEN_BIAS_INIT is not None:
                for hidden in self.linears[:-1]:
                    hidden.bias.fill_(HIDDEN_BIAS_INIT)
            last.bias.zero_()
            last.bias[0] = cfg.init_density / (cfg.zeta * INV_SQRT_4PI)
        scale = torch.full((2 * self.k,), float(cfg.directional_scale), dtype=torch.float64)
        scale[0] = scale[self.k] = 1.0  # Re and Im of c_00
        self.register_buffer("out_scale", scale, persistent=False)
        box = cfg.scene_box
        self.register_buffer("box_min", torch.tensor(box.min, dtype=torch.float32), persistent=False)
        self.register_buffer("box_size", torch.tensor(box.size, dtype=torch.float32), persistent=False)
        self._degree_hook: torch.utils.hooks.RemovableHandle | None = None
        self._level_weights: torch.Tensor | None = None

    # ----------------------------------------------------------------- ScatteringField
    @property
    def config(self) -> FieldConfig:
        return self.cfg

    @property
    def device(self) -> torch.device:
        return device_dtype(self)[0]

    @property
    def dtype(self) -> torch.dtype:
        return device_dtype(self)[1]

    def set_active_degree(self, degree: int | None) -> None:
        """Progressive SH: zero the coefficients above ``degree`` (None or >= L: all active), by
        masking the output layer, so every evaluation path (forward, coefficients) sees it."""
        if self._degree_hook is not None:
            self._degree_hook.remove()
            self._degree_hook = None
        if degree is None or degree >= self.cfg.sh_degree:
            return
        k, keep = self.cfg.num_coefficients, (degree + 1) ** 2
        mask = torch.ones(2 * k)
        mask[keep:k] = 0
        mask[k + keep:] = 0

        def hook(_mod, _inp, out):
            return out * mask.to(out.device, out.dtype)

        self._degree_hook = self.linears[-1].register_forward_hook(hook)

    def set_active_levels(self, levels: float | None) -> None:
        """Coarse-to-fine: weight the hash levels by :func:`level_window` for ``levels`` active
        levels (None or >= the level count: all at 1, nothing applied)."""
        enc = self.cfg.encoding
        if levels is None or levels >= enc.n_levels:
            self._level_weights = None
            return
        self._level_weights = level_window(enc.n_levels, enc.n_features, float(levels))

    def _encode(self, u: torch.Tensor) -> torch.Tensor:
        h = self.encoding(u)
        return h if self._level_weights is None else h * self._level_weights.to(h.device, h.dtype)

    def _encode_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h, jac = self.encoding.forward_with_jacobian(u)
        if self._level_weights is None:
            return h, jac
        w = self._level_weights.to(h.device, h.dtype)
        return h * w, jac * w

    # ----------------------------------------------------------------- internals
    def _check_points(self, x: torch.Tensor, name: str = "x") -> None:
        if x.ndim != 2 or x.shape[1] != 3:
            raise ShsasError(f"field: {name} must have shape (P, 3), got {tuple(x.shape)}")

    def _unit(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """u = (x - min) / size and the inside-box mask (P,) as 0/1, in the parameters' dtype
        (points may come in float64; the network runs in its own dtype)."""
        u = (x - self.box_min.to(x.dtype)) / self.box_size.to(x.dtype)
        dt = self.encoding.table.dtype
        ok = ((u >= 0) & (u <= 1)).all(dim=1)  # False for NaN too
        # points outside (or NaN) read the grid at the origin; their outputs are zeroed anyway
        u = torch.where(ok[:, None], u, torch.zeros_like(u))
        return u.to(dt), ok.to(dt)

    def _mlp(self, h: torch.Tensor) -> torch.Tensor:
        for i, lin in enumerate(self.linears):
            h = lin(h)
            if i < len(self.linears) - 1:
                h = torch.relu(h)
        return self._scaled(h)

    def _scaled(self, out: torch.Tensor) -> torch.Tensor:
        """Apply ``directional_scale`` to the degree >= 1 columns (nothing to do at L = 0)."""
        return out if self.k == 1 else out * self.out_scale.to(out.dtype)

    def _mlp_with_dc_gradient(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """MLP output (P, 2K) and d|c_00| / d h (P, D), the gradient of the DC magnitude with
        respect to the encoded features.

        One reverse (vector-Jacobian) pass per point: |c_00| is a single output, so its gradient
        costs one matmul per layer, where forward-mode tangents would cost three (one per axis).
        The ReLU masks of the forward pass are reused; the result stays differentiable in the
        parameters, so training needs only a first-order backward.
        """
        masks = []
        n = len(self.linears)
        for i, lin in enumerate(self.linears):
            h = lin(h)
            if i < n - 1:
                m = (h > 0).to(h.dtype)
                h = h * m
                masks.append(m)
        re, im = h[:, 0], h[:, self.k]
        a = _safe_abs(re, im)
        inv = torch.where(a > 0, 1.0 / torch.where(a > 0, a, torch.ones_like(a)), torch.zeros_like(a))
        # d|c| / d out = (re, im) / |c| on the two DC columns: a per-point mix of two weight rows
        w_last = self.linears[-1].weight
        v = (re * inv)[:, None] * w_last[0] + (im * inv)[:, None] * w_last[self.k]  # (P, hidden)
        for lin, m in zip(reversed(self.linears[:-1]), reversed(masks), strict=True):
            v = (v * m) @ lin.weight
        return self._scaled(h), v  # the DC columns are not scaled, so v stands

    def _raw(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Real and imaginary coefficient parts (P, K) each, zero outside the box."""
        self._check_points(x)
        u, inside = self._unit(x)
        out = self._mlp(self._encode(u)) * inside[:, None]
        return out[:, : self.k], out[:, self.k :]

    def _dc_abs(self, x: torch.Tensor) -> torch.Tensor:
        re, im = self._raw(x)
        return _safe_abs(re[:, 0], im[:, 0]) * INV_SQRT_4PI

    # ----------------------------------------------------------------- public API
    def coefficients(self, x: torch.Tensor) -> torch.Tensor:
        """Complex SH coefficients c_lm(x): x (P,3) m -> (P, (L+1)^2) complex."""
        re, im = self._raw(x)
        return torch.complex(re, im)

    def density(self, x: torch.Tensor) -> torch.Tensor:
        """ρ(x) = |c_00| / √(4π) · ζ: x (P,3) m -> (P,) >= 0, 1/m."""
        return self._dc_abs(x) * self.cfg.zeta

    def scattering(self, x: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """σ(x, ω) = Σ c_lm(x) Y_lm(ω): x (P,3) m, dirs (P,3) unit receiver->x -> (P,) complex."""
        self._check_points(dirs, "dirs")
        re, im = self._raw(x)
        y = sh_basis(dirs, self.degree).to(re.dtype)
        return torch.complex((re * y).sum(1), (im * y).sum(1))

    def normals(self, x: torch.Tensor, create_graph: bool = False) -> torch.Tensor:
        """n(x) = -∇|σ_DC| / ‖∇|σ_DC|‖: x (P,3) m -> (P,3) unit (0 where the gradient is 0).

        ``create_graph=True`` keeps the result differentiable w.r.t. the parameters (training).
        """
        if self.cfg.backend != "reference":
            with torch.set_grad_enabled(create_graph or torch.is_grad_enabled()):
                out = self._fast_pass(x, None, with_normals=True)
            n = out["normals"]
            return n if create_graph else n.detach()
        self._check_points(x)
        return normals_by_autograd(self._dc_abs, x, create_graph=create_graph)

    def forward(
        self, x: torch.Tensor, dirs: torch.Tensor, with_normals: bool = True, create_graph: bool | None = None
    ) -> dict[str, torch.Tensor]:
        """Everything the renderer needs from one encoding evaluation.

        Args:
            x: (P, 3) world points, m.
            dirs: (P, 3) unit directions receiver -> x.
            with_normals: also compute normals.
            create_graph: keep normals differentiable; default ``torch.is_grad_enabled()``.

        Returns:
            dict with ``density`` (P,) real >= 0, ``scattering`` (P,) complex, ``dc`` (P,)
            complex σ_DC = c_00/√(4π), and when ``with_normals`` ``normals`` (P, 3) and
            ``gradient`` (P, 3) ∇|σ_DC| in 1/m² (world frame; the normal is its negative, normalised).
        """
        self._check_points(dirs, "dirs")
        if create_graph is None:
            create_graph = torch.is_grad_enabled()
        if self.cfg.backend != "reference":
            return self._fast_pass(x, dirs, with_normals, create_graph)
        if not with_normals:
            re, im = self._raw(x)
            return self._assemble(re, im, dirs)
        # share the encoding between outputs and the normal: one graph from a grad-leaf x
        with torch.enable_grad():
            xg = x if x.requires_grad else x.detach().requires_grad_(True)
            re, im = self._raw(xg)
            out = self._assemble(re, im, dirs)
            dc_abs = out["density"] / self.cfg.zeta
            if dc_abs.requires_grad:
                (g,) = torch.autograd.grad(dc_abs.sum(), xg, create_graph=create_graph, retain_graph=True)
            else:
                g = torch.zeros_like(x)
        n = -safe_normalize(g)
        out["normals"] = n if create_graph else n.detach()
        out["gradient"] = g if create_graph else g.detach()
        if not torch.is_grad_enabled():
            out = {k: v.detach() for k, v in out.items()}
        return out

    def _assemble(self, re: torch.Tensor, im: torch.Tensor, dirs: torch.Tensor | None) -> dict[str, torch.Tensor]:
        dc_re, dc_im = re[:, 0] * INV_SQRT_4PI, im[:, 0] * INV_SQRT_4PI
        out = {"density": _safe_abs(dc_re, dc_im) * self.cfg.zeta, "dc": torch.complex(dc_re, dc_im)}
        if dirs is not None:
            y = sh_basis(dirs, self.degree).to(re.dtype)
            out["scattering"] = torch.complex((re * y).sum(1), (im * y).sum(1))
        return out

    def _fast_pass(
        self, x: torch.Tensor, dirs: torch.Tensor | None, with_normals: bool, create_graph: bool = True
    ) -> dict[str, torch.Tensor]:
        self._check_points(x)
        u, inside = self._unit(x)
        if not with_normals:
            out = self._mlp(self._encode(u)) * inside[:, None]
            return self._assemble(out[:, : self.k], out[:, self.k :], dirs)
        h, jac = self._encode_with_jacobian(u)  # (P, D), (3, P, D) = d h / d u_a
        out, v = self._mlp_with_dc_gradient(h)
        out = out * inside[:, None]
        re, im = out[:, : self.k], out[:, self.k :]
        res = self._assemble(re, im, dirs)
        # ∇_x |σ_DC| = Σ_d (d|c_00|/d h_d) (d h_d / d u_a) / size_a / √(4π), 0 outside the box
        g = (jac * v).sum(-1).t() / self.box_size.to(jac.dtype) * (inside * INV_SQRT_4PI)[:, None]
        n = -safe_normalize(g)
        res["normals"] = n if create_graph else n.detach()
        res["gradient"] = g if create_graph else g.detach()
        return res
