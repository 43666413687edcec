"""PanoMan for PyTorch: the posed mesh as a differentiable function of α, β, rotation and
translation.

``pose`` is a ``torch.autograd.Function``: the forward pass calls the Rust ``pose`` (batched,
in parallel, the GIL released) with g's frame solve polished to its minimiser; the backward
pass calls the Rust vector–Jacobian product ``Model.pose_vjp``, which is exact — g is
differentiated through its frame solve (implicit function theorem, docs/design/rla-and-g.md
§3.8), α through the rest shape and g's gauge, the correction MLP within its ReLU pattern.
``PanoManLayer`` wraps it as an ``nn.Module`` with differentiable keypoints, like ``smplx``'s
body models::

    import torch, panoman, panoman.torch as pt
    layer = pt.PanoManLayer(panoman.Model.load("M.safetensors"))
    alpha = torch.zeros(1, layer.n_shape, requires_grad=True)
    beta = torch.zeros(1, layer.n_beta, requires_grad=True)
    out = layer(alpha=alpha, beta=beta)          # out.vertices (1, V, 3), out.keypoints (1, 133, 3)
    out.keypoints[:, 0].norm().backward()        # alpha.grad, beta.grad

β is flat: every block's coefficients concatenated in ``model.blocks`` order
(``layer.beta_slices`` names the ranges; ``layer.beta_from_dict`` builds it from a dict).
Computation runs on the CPU in float64; results come back in the inputs' dtype and device.
Double backward is not supported; a non-finite upstream gradient raises ``InvalidError``
(naming the vertex) rather than propagating.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch.autograd.function import once_differentiable

from ._panoman import Model

__all__ = ["PanoManLayer", "PanoManOutput", "pose"]


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().to("cpu", torch.float64).contiguous().numpy()


class _Pose(torch.autograd.Function):
    @staticmethod
    def forward(ctx, model, correction, alpha, beta, rotation, translation):
        ctx.model = model
        ctx.correction = correction
        ctx.save_for_backward(alpha, beta, rotation, translation)
        v = model.pose_flat(_np(alpha), _np(beta), _np(rotation), _np(translation),
                            correction=correction, precise=True)
        return torch.from_numpy(v).to(device=alpha.device, dtype=alpha.dtype)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad):
        alpha, beta, rotation, translation = ctx.saved_tensors
        if not any(ctx.needs_input_grad[2:]):
            return None, None, None, None, None, None
        g = ctx.model.pose_vjp(_np(alpha), _np(beta), _np(rotation), _np(translation),
                               _np(grad), correction=ctx.correction)

        def back(name, like, i):
            if not ctx.needs_input_grad[i]:
                return None
            return torch.from_numpy(g[name]).to(device=like.device, dtype=like.dtype)

        return (None, None, back("alpha", alpha, 2), back("beta", beta, 3),
                back("rotation", rotation, 4), back("translation", translation, 5))


def pose(model: Model, alpha: torch.Tensor, beta: torch.Tensor,
         rotation: torch.Tensor | None = None, translation: torch.Tensor | None = None,
         correction: bool = True) -> torch.Tensor:
    """The posed vertices ``(B, V, 3)`` (metres) of ``alpha (B, S)``, flat ``beta (B, K)``,
    ``rotation (B, 3)`` (axis-angle, radians) and ``translation (B, 3)`` (metres; both zero
    when omitted), differentiable with respect to all four."""
    if alpha.dim() != 2 or beta.dim() != 2 or alpha.shape[0] != beta.shape[0]:
        raise ValueError(f"pose: alpha (B, S) and beta (B, K) expected, got {tuple(alpha.shape)} "
                         f"and {tuple(beta.shape)}")
    b = alpha.shape[0]
    zeros = alpha.new_zeros(b, 3)
    rotation = zeros if rotation is None else rotation
    translation = zeros if translation is None else translation
    return _Pose.apply(model, correction, alpha, beta, rotation, translation)


class PanoManOutput(NamedTuple):
    """What ``PanoManLayer`` returns: ``vertices (B, V, 3)`` and ``keypoints (B, 133, 3)``
    (metres; without the batch dimension when the inputs had none)."""

    vertices: torch.Tensor
    keypoints: torch.Tensor


class PanoManLayer(torch.nn.Module):
    """A PanoMan model as a module: ``forward(alpha, beta, rotation, translation)`` →
    ``PanoManOutput``. Inputs are ``(B, ·)`` or unbatched ``(·,)``; omitted ones are zero
    (``beta`` zero is every block's zero coefficients, as ``Model.pose`` with no β). The
    keypoints are the model's fixed sparse rows of vertices (a differentiable ``index_add``).
    """

    def __init__(self, model: Model, correction: bool = True, dtype=torch.float32):
        super().__init__()
        self.model = model
        self.correction = correction
        self.n_shape = model.n_shape
        self.beta_slices: dict[str, slice] = {}
        off = 0
        for name, k in model.blocks.items():
            self.beta_slices[name] = slice(off, off + k)
            off += k
        self.n_beta = off
        self.dtype = dtype
        k, v, w = model.keypoint_rows
        self.register_buffer("kp_index", torch.from_numpy(k))
        self.register_buffer("kp_vertex", torch.from_numpy(v))
        # float64 (the model's weights), cast to the vertices' dtype where used.
        self.register_buffer("kp_weight", torch.from_numpy(w))
        self.n_keypoints = len(model.keypoint_names)
        self.register_buffer("faces", torch.from_numpy(model.faces))

    def beta_from_dict(self, blocks: dict[str, torch.Tensor], batch: int = 1) -> torch.Tensor:
        """A flat β ``(B, K)`` from ``{block: (B, k)}`` (missing blocks zero; differentiable)."""
        unknown = set(blocks) - set(self.beta_slices)
        if unknown:
            raise ValueError(f"unknown β blocks {sorted(unknown)}; the model's are "
                             f"{list(self.beta_slices)}")
        like = next(iter(blocks.values()), None)
        n = like.shape[0] if like is not None and like.dim() == 2 else batch
        dtype = like.dtype if like is not None else self.dtype
        device = like.device if like is not None else self.kp_weight.device
        parts = []
        for name, sl in self.beta_slices.items():
            if name in blocks:
                t = blocks[name]
                parts.append(t if t.dim() == 2 else t[None])
            else:
                parts.append(torch.zeros(n, sl.stop - sl.start, dtype=dtype, device=device))
        return torch.cat(parts, dim=1)

    def keypoints(self, vertices: torch.Tensor) -> torch.Tensor:
        """The keypoints ``(B, 133, 3)`` of vertices ``(B, V, 3)``."""
        dev = vertices.device
        w = self.kp_weight.to(device=dev, dtype=vertices.dtype)
        picked = vertices[:, self.kp_vertex.to(dev), :] * w[None, :, None]
        out = vertices.new_zeros(vertices.shape[0], self.n_keypoints, 3)
        return out.index_add(1, self.kp_index.to(dev), picked)

    def forward(self, alpha=None, beta=None, rotation=None, translation=None) -> PanoManOutput:
        given = [t for t in (alpha, beta, rotation, translation) if t is not None]
        ref = given[0] if given else self.kp_weight
        unbatched = bool(given) and ref.dim() == 1
        lift = (lambda t: t[None]) if unbatched else (lambda t: t)
        b = 1 if unbatched or not given else ref.shape[0]
        dt = ref.dtype if given and ref.is_floating_point() else self.dtype

        def get(t, n):
            return ref.new_zeros(b, n, dtype=dt) if t is None else lift(t)

        alpha = get(alpha, self.n_shape)
        beta = get(beta, self.n_beta)
        if alpha.shape[1] != self.n_shape or beta.shape[1] != self.n_beta:
            raise ValueError(f"alpha (B, {self.n_shape}) and beta (B, {self.n_beta}) expected, "
                             f"got {tuple(alpha.shape)} and {tuple(beta.shape)}")
        verts = pose(self.model, alpha, beta, get(rotation, 3), get(translation, 3),
                     self.correction)
        kps = self.keypoints(verts)
        if unbatched:
            return PanoManOutput(verts[0], kps[0])
        return PanoManOutput(verts, kps)
