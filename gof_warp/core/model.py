"""The 3D Gaussian model: raw parameters, activations, initialisation, 3DGS PLY interchange.

Raw (optimised) parameters, all torch tensors on one device, N Gaussians:

============== ============ ===========================================================
name            shape        meaning
============== ============ ===========================================================
means           [N, 3]       centres μ, world space
quats           [N, 4]       rotation as a quaternion **wxyz**, not necessarily unit
log_scales      [N, 3]       log of the standard deviations along the local axes
opacity_logits  [N]          logit of the opacity
sh_dc           [N, 3]       degree-0 spherical-harmonic coefficient per RGB channel
sh_rest         [N, K-1, 3]  degree 1..D coefficients, K = (D+1)², D = ``max_sh_degree``
============== ============ ===========================================================

Activations: ``rotations = quats / |quats|``, ``scales = exp(log_scales)``,
``opacities = sigmoid(opacity_logits)``, colour = SH(direction) + 0.5 (3DGS convention).

Optional 3D smoothing filter (Mip-Splatting, as GOF uses it): a per-Gaussian variance ``filter_3d``
(``φ``, [N], not optimised). When set, :attr:`Gaussians.scales` and :attr:`Gaussians.opacities`
return the *filtered* values ``s_f = sqrt(s² + φ²)`` and ``o_f = o · sqrt(Π s² / Π(s² + φ²))``;
the unfiltered ones are :attr:`raw_scales` / :attr:`raw_opacities`.

PLY interchange uses the standard 3D Gaussian Splatting layout (``x y z nx ny nz f_dc_0..2
f_rest_0..(3(K-1)-1) opacity scale_0..2 rot_0..3``, raw values: logit opacity, log scales,
unnormalised wxyz quaternion; ``f_rest`` channel-major: ``f_rest_{c*(K-1)+k} = sh_rest[:, k, c]``),
so models from other 3DGS tools load and ours open in splat viewers. GOF's extra ``filter_3D``
column is read and written when present.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np
import torch

from .errors import ModelError, PlyError, error_summary
from .ply import read_ply_vertices, write_ply_vertices

log = logging.getLogger(__name__)

SH_C0 = 0.28209479177387814
PARAM_NAMES = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


def num_sh_coeffs(degree: int) -> int:
    """K = (degree + 1)² coefficients per channel."""
    return (degree + 1) ** 2


def rgb_to_sh_dc(rgb):
    """Colour in [0, 1] → degree-0 SH coefficient (inverse of ``SH_C0 · dc + 0.5``)."""
    return (rgb - 0.5) / SH_C0


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """``[N, 4]`` quaternions (wxyz, any non-zero length) → ``[N, 3, 3]`` rotation matrices."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    return torch.stack(rows, dim=-1).reshape(*quats.shape[:-1], 3, 3)


def _default_device():
    from .devices import resolve_device

    return resolve_device()


def activate_rotations(quats: torch.Tensor) -> torch.Tensor:
    """``[N, 4]`` unit quaternions (wxyz) from the raw ``[N, 4]`` ones."""
    return torch.nn.functional.normalize(quats, dim=1)


def activate_scales(log_scales: torch.Tensor, filter_3d: torch.Tensor | None) -> torch.Tensor:
    """``[N, 3]`` standard deviations ``exp(log_scales)``, filtered ``√(s² + φ²)`` when ``filter_3d`` ``[N]`` is set."""
    s = torch.exp(log_scales)
    if filter_3d is None:
        return s
    return torch.sqrt(s * s + filter_3d[:, None] ** 2)


def activate_opacities(opacity_logits: torch.Tensor, log_scales: torch.Tensor,
                       filter_3d: torch.Tensor | None) -> torch.Tensor:
    """``[N]`` opacities ``sigmoid(opacity_logits)``, times the 3D filter's energy compensation
    ``√(Π s² / Π (s² + φ²))`` when ``filter_3d`` ``[N]`` is set."""
    o = torch.sigmoid(opacity_logits)
    if filter_3d is None:
        return o
    s2 = torch.exp(log_scales) ** 2
    f2 = s2 + filter_3d[:, None] ** 2
    # products written out: torch.prod's backward reads a zero count back to the host (a GPU sync)
    ratio = (s2[:, 0] * s2[:, 1] * s2[:, 2]) / (f2[:, 0] * f2[:, 1] * f2[:, 2])
    return o * torch.sqrt(ratio)


def activate(quats: torch.Tensor, log_scales: torch.Tensor, opacity_logits: torch.Tensor,
             filter_3d: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(rotations [N, 4], scales [N, 3], opacities [N])`` from the raw parameters: what
    :attr:`Gaussians.rotations`, :attr:`Gaussians.scales` and :attr:`Gaussians.opacities` compute, in that order
    (eager, the same operations and so the same bits and gradients)."""
    return (activate_rotations(quats), activate_scales(log_scales, filter_3d),
            activate_opacities(opacity_logits, log_scales, filter_3d))


def activate_pointwise(quats: torch.Tensor, log_scales: torch.Tensor, opacity_logits: torch.Tensor,
                       filter_3d: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`activate` with the quaternion's norm written as the root of its four squares and each component divided
    on its own, for the compiler: without a reduction op in the forward or the backward (``F.normalize``'s norm, and
    the gradient of a row-broadcast division, are reductions over the 4 components) inductor fuses everything into one
    pointwise kernel each way instead of a row-reduction kernel (which costs 0.24 ms each way for 781k Gaussians on
    an H100). Within one float32 rounding of :func:`activate`'s rotations."""
    q0, q1, q2, q3 = quats.unbind(1)
    norm = torch.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3).clamp_min(1e-12)  # F.normalize's eps
    rotations = torch.stack([q0 / norm, q1 / norm, q2 / norm, q3 / norm], dim=1)
    return rotations, activate_scales(log_scales, filter_3d), activate_opacities(opacity_logits, log_scales, filter_3d)


@dataclasses.dataclass(frozen=True)
class ActivatedGaussians:
    """A model's activated parameters for one render (:meth:`Gaussians.activated`); the attributes
    :func:`~gof_warp.rendering.render.render` reads."""

    means: torch.Tensor  # [N, 3]
    rotations: torch.Tensor  # [N, 4] unit wxyz
    scales: torch.Tensor  # [N, 3]
    opacities: torch.Tensor  # [N]
    sh_dc: torch.Tensor  # [N, 3]
    sh_rest: torch.Tensor  # [N, K-1, 3]
    active_sh_degree: int


class Activation:
    """:func:`activate`, compiled with ``torch.compile`` when ``compiled`` (as :func:`activate_pointwise`: one fused
    kernel forward and one backward instead of ~40 small elementwise ones over the Gaussians, with dynamic ``N``, so
    densification does not recompile), else eager. Unless ``strict``, a compiler failure in the forward falls back to
    eager with a warning; one in the backward is the caller's to catch (:meth:`give_up`). ``backend``:
    ``torch.compile``'s (tests use ``"aot_eager"``, which needs no C++ or Triton compiler)."""

    def __init__(self, compiled: bool, strict: bool = False, backend="inductor"):
        self.strict = bool(strict)
        self._compiled_fn = (torch.compile(activate_pointwise, dynamic=True, fullgraph=True, backend=backend)
                             if compiled else None)
        self.fallback_reason: str | None = None

    @property
    def compiled(self) -> bool:
        """Whether calls go through the compiled function (False from the start, or after :meth:`give_up`)."""
        return self._compiled_fn is not None

    def __call__(self, quats, log_scales, opacity_logits, filter_3d):
        if self._compiled_fn is None:
            return activate(quats, log_scales, opacity_logits, filter_3d)
        try:
            return self._compiled_fn(quats, log_scales, opacity_logits, filter_3d)
        except Exception as e:  # noqa: BLE001 - any compiler failure: the eager function computes the same
            if self.strict:
                raise
            self.give_up(e)
            return activate(quats, log_scales, opacity_logits, filter_3d)

    def give_up(self, error: Exception) -> None:
        """Eager from now on, keeping why (a warning)."""
        if self.compiled:
            self.fallback_reason = error_summary(error)
            log.warning("torch.compile of the activations failed (%s); using the eager ones", self.fallback_reason)
        self._compiled_fn = None


class Gaussians:
    """A set of 3D Gaussians (see module docstring for the parameters and conventions)."""

    def __init__(self, means, quats, log_scales, opacity_logits, sh_dc, sh_rest=None, *,
                 max_sh_degree: int | None = None, active_sh_degree: int | None = None, filter_3d=None,
                 requires_grad: bool = False):
        means = torch.as_tensor(means, dtype=torch.float32)
        device = means.device
        as_t = lambda x: torch.as_tensor(x, dtype=torch.float32, device=device)  # noqa: E731
        n = means.shape[0] if means.ndim == 2 else -1
        if max_sh_degree is None:
            k_rest = 0 if sh_rest is None else torch.as_tensor(sh_rest).shape[1]
            max_sh_degree = int(round(math.sqrt(k_rest + 1))) - 1
        if sh_rest is None:
            sh_rest = torch.zeros((max(n, 0), num_sh_coeffs(max_sh_degree) - 1, 3), device=device)
        self.params: dict[str, torch.Tensor] = {
            "means": means,
            "quats": as_t(quats),
            "log_scales": as_t(log_scales),
            "opacity_logits": as_t(opacity_logits),
            "sh_dc": as_t(sh_dc),
            "sh_rest": as_t(sh_rest),
        }
        self.max_sh_degree = int(max_sh_degree)
        self.active_sh_degree = self.max_sh_degree if active_sh_degree is None else int(active_sh_degree)
        self.filter_3d = None if filter_3d is None else as_t(filter_3d)
        self._check_shapes()
        if requires_grad:
            self.requires_grad_(True)

    # ------------------------------------------------------------------ validation
    def _check_shapes(self):
        p = self.params
        if p["means"].ndim != 2 or p["means"].shape[1] != 3:
            raise ModelError(f"means must be [N, 3], got {tuple(p['means'].shape)}")
        n = p["means"].shape[0]
        k = num_sh_coeffs(self.max_sh_degree)
        if not 0 <= self.max_sh_degree <= 3:
            raise ModelError(f"max_sh_degree must be 0..3, got {self.max_sh_degree}")
        if not 0 <= self.active_sh_degree <= self.max_sh_degree:
            raise ModelError(f"active_sh_degree must be 0..{self.max_sh_degree}, got {self.active_sh_degree}")
        expected = {
            "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,), "sh_dc": (n, 3), "sh_rest": (n, k - 1, 3),
        }
        for name, shape in expected.items():
            if tuple(p[name].shape) != shape:
                raise ModelError(f"{name} must have shape {list(shape)} for N={n}, got {list(p[name].shape)}")
            if p[name].device != p["means"].device:
                raise ModelError(f"{name} is on {p[name].device}, means on {p['means'].device}")
        if self.filter_3d is not None and tuple(self.filter_3d.shape) != (n,):
            raise ModelError(f"filter_3d must have shape [{n}], got {list(self.filter_3d.shape)}")

    def validate(self, where: str = "Gaussians") -> "Gaussians":
        """Raise :class:`ModelError` on NaN/inf parameters or zero-length quaternions. Returns self."""
        with torch.no_grad():
            for name, t in self.params.items():
                bad = ~torch.isfinite(t)
                if bad.any():
                    rows = torch.nonzero(bad.reshape(t.shape[0], -1).any(dim=1)).flatten()
                    raise ModelError(
                        f"{where}: {name} has NaN/inf values in {rows.numel()} Gaussian(s), e.g. index {rows[:5].tolist()}"
                    )
            qn = self.params["quats"].norm(dim=1)
            if (qn < 1e-12).any():
                idx = torch.nonzero(qn < 1e-12).flatten()[:5].tolist()
                raise ModelError(f"{where}: zero-length quaternion(s) at index {idx}")
        return self

    # ------------------------------------------------------------------ raw parameters
    def __len__(self) -> int:
        return self.params["means"].shape[0]

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    @property
    def means(self) -> torch.Tensor:
        return self.params["means"]

    @property
    def quats(self) -> torch.Tensor:
        return self.params["quats"]

    @property
    def log_scales(self) -> torch.Tensor:
        return self.params["log_scales"]

    @property
    def opacity_logits(self) -> torch.Tensor:
        return self.params["opacity_logits"]

    @property
    def sh_dc(self) -> torch.Tensor:
        return self.params["sh_dc"]

    @property
    def sh_rest(self) -> torch.Tensor:
        return self.params["sh_rest"]

    # ------------------------------------------------------------------ activations
    @property
    def rotations(self) -> torch.Tensor:
        """[N, 4] unit quaternions (wxyz)."""
        return activate_rotations(self.quats)

    @property
    def raw_scales(self) -> torch.Tensor:
        """[N, 3] standard deviations without the 3D filter."""
        return torch.exp(self.log_scales)

    @property
    def raw_opacities(self) -> torch.Tensor:
        """[N] opacities without the 3D filter."""
        return torch.sigmoid(self.opacity_logits)

    @property
    def scales(self) -> torch.Tensor:
        """[N, 3] standard deviations, with the 3D filter when one is set."""
        return activate_scales(self.log_scales, self.filter_3d)

    @property
    def opacities(self) -> torch.Tensor:
        """[N] opacities, with the 3D filter's energy compensation when one is set."""
        return activate_opacities(self.opacity_logits, self.log_scales, self.filter_3d)

    def activated(self, fn=None) -> "ActivatedGaussians":
        """The model as :func:`~gof_warp.rendering.render.render` reads it, its activations made by one call of ``fn``
        (default :func:`activate`, the properties' arithmetic; the trainer passes an :class:`Activation`, compiled on
        CUDA). Gradients reach the raw parameters as through the properties."""
        rotations, scales, opacities = (fn or activate)(self.quats, self.log_scales, self.opacity_logits,
                                                        self.filter_3d)
        return ActivatedGaussians(self.means, rotations, scales, opacities, self.sh_dc, self.sh_rest,
                                  self.active_sh_degree)

    @property
    def sh(self) -> torch.Tensor:
        """[N, K, 3] all SH coefficients (dc first)."""
        return torch.cat([self.sh_dc[:, None, :], self.sh_rest], dim=1)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_points(cls, points, colors=None, *, sh_degree: int = 3, init_opacity: float = 0.1,
                    device=None, min_scale: float = 1e-7) -> "Gaussians":
        """One isotropic Gaussian per point (3DGS initialisation).

        Args:
            points: [N, 3] positions.
            colors: [N, 3] uint8 or float in [0, 1]; grey when None.
            sh_degree: maximum SH degree D (active degree starts at 0).
            init_opacity: initial opacity (GOF/3DGS: 0.1).
        Scale: sqrt of the mean squared distance to the 3 nearest neighbours (clamped at ``min_scale``).
        """
        from scipy.spatial import cKDTree

        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            raise ModelError("cannot initialise Gaussians from zero points")
        if not np.all(np.isfinite(pts)):
            raise ModelError("initial points contain NaN/inf")
        if colors is None:
            rgb = np.full((len(pts), 3), 0.5)
        else:
            rgb = np.asarray(colors)
            rgb = rgb.astype(np.float64) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float64)
            if rgb.shape != pts.shape:
                raise ModelError(f"colors must be [N, 3] like points, got {rgb.shape}")
        k = min(4, len(pts))
        if k > 1:
            d, _ = cKDTree(pts).query(pts, k=k)
            mean_sq = np.mean(d[:, 1:] ** 2, axis=1)
        else:
            mean_sq = np.ones(len(pts))
        scale = np.sqrt(np.maximum(mean_sq, min_scale**2))
        n = len(pts)
        device = device or _default_device()
        quats = np.zeros((n, 4)); quats[:, 0] = 1.0
        return cls(
            means=torch.tensor(pts, dtype=torch.float32, device=device),
            quats=quats,
            log_scales=np.repeat(np.log(scale)[:, None], 3, axis=1),
            opacity_logits=np.full(n, math.log(init_opacity / (1 - init_opacity))),
            sh_dc=rgb_to_sh_dc(rgb),
            max_sh_degree=sh_degree,
            active_sh_degree=0,
        )

    @classmethod
    def from_activated(cls, means, rotations, scales, opacities, colors=None, *, sh=None, device=None) -> "Gaussians":
        """Build from activated values (e.g. another tool's arrays): scales > 0, opacities in [0, 1].

        Args:
            means: [N, 3]; rotations: [N, 4] wxyz (any non-zero length); scales: [N, 3] > 0;
            opacities: [N] in [0, 1] (clamped to [1e-6, 1 - 1e-6] for the logit);
            colors: [N, 3] in [0, 1] (degree-0 SH) or ``sh``: [N, K, 3] coefficients.
        """
        as_np = lambda x, name: np.asarray(x.detach().cpu() if torch.is_tensor(x) else x, dtype=np.float64)  # noqa: E731
        m, q, s, o = (as_np(means, "means"), as_np(rotations, "rotations"), as_np(scales, "scales"),
                      as_np(opacities, "opacities"))
        n = len(m)
        for name, a in (("means", m), ("rotations", q), ("scales", s), ("opacities", o)):
            if not np.all(np.isfinite(a)):
                raise ModelError(f"{name} contain NaN/inf")
        if s.shape != (n, 3) or (s <= 0).any():
            bad = np.nonzero((s <= 0).any(axis=1))[0][:5].tolist() if s.shape == (n, 3) else []
            raise ModelError(f"scales must be [N, 3] and positive; non-positive at index {bad}" if bad
                             else f"scales must be [N, 3], got {s.shape}")
        if o.shape != (n,) or (o < 0).any() or (o > 1).any():
            raise ModelError(f"opacities must be [N] in [0, 1], got shape {o.shape}, range "
                             f"[{o.min() if o.size else 0}, {o.max() if o.size else 0}]")
        o = np.clip(o, 1e-6, 1 - 1e-6)
        if sh is not None:
            sh = as_np(sh, "sh")
            dc, rest = sh[:, 0, :], sh[:, 1:, :]
        else:
            rgb = np.full((n, 3), 0.5) if colors is None else as_np(colors, "colors")
            dc, rest = rgb_to_sh_dc(rgb), np.zeros((n, 0, 3))
        device = device or (means.device if torch.is_tensor(means) else _default_device())
        g = cls(means=torch.tensor(m, dtype=torch.float32, device=device), quats=q, log_scales=np.log(s),
                opacity_logits=np.log(o / (1 - o)), sh_dc=dc, sh_rest=rest)
        return g.validate()

    @classmethod
    def random_in_box(cls, n: int, lo=(-1.3, -1.3, -1.3), hi=(1.3, 1.3, 1.3), *, seed: int = 0, **kw) -> "Gaussians":
        """``n`` Gaussians uniformly in an axis-aligned box with random colours (3DGS's Blender init)."""
        rng = np.random.default_rng(seed)
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        pts = lo + (hi - lo) * rng.random((n, 3))
        return cls.from_points(pts, rng.random((n, 3)), **kw)

    # ------------------------------------------------------------------ torch plumbing
    def requires_grad_(self, flag: bool = True) -> "Gaussians":
        for k in PARAM_NAMES:
            self.params[k] = self.params[k].detach().requires_grad_(flag)
        return self

    def to(self, device) -> "Gaussians":
        return self._map(lambda t: t.to(device))

    def detach(self) -> "Gaussians":
        return self._map(lambda t: t.detach())

    def clone(self) -> "Gaussians":
        return self._map(lambda t: t.detach().clone())

    def subset(self, index) -> "Gaussians":
        """Gaussians selected by a boolean mask or an index tensor."""
        return self._map(lambda t: t[index])

    def _map(self, fn) -> "Gaussians":
        return Gaussians(**{k: fn(v) for k, v in self.params.items()}, max_sh_degree=self.max_sh_degree,
                         active_sh_degree=self.active_sh_degree,
                         filter_3d=None if self.filter_3d is None else fn(self.filter_3d))

    def __repr__(self) -> str:
        return f"Gaussians(N={len(self)}, sh_degree={self.active_sh_degree}/{self.max_sh_degree}, device={self.device})"

    # ------------------------------------------------------------------ PLY interchange
    def save_ply(self, path) -> None:
        """Write the 3DGS PLY layout (atomically)."""
        p = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in self.params.items()}
        n = len(self)
        cols = {"x": p["means"][:, 0], "y": p["means"][:, 1], "z": p["means"][:, 2]}
        for a in ("nx", "ny", "nz"):
            cols[a] = np.zeros(n, np.float32)
        for c in range(3):
            cols[f"f_dc_{c}"] = p["sh_dc"][:, c]
        rest = p["sh_rest"].transpose(0, 2, 1).reshape(n, 3 * p["sh_rest"].shape[1])  # channel-major, as 3DGS
        for i in range(rest.shape[1]):
            cols[f"f_rest_{i}"] = rest[:, i]
        cols["opacity"] = p["opacity_logits"]
        for i in range(3):
            cols[f"scale_{i}"] = p["log_scales"][:, i]
        for i in range(4):
            cols[f"rot_{i}"] = p["quats"][:, i]
        if self.filter_3d is not None:
            cols["filter_3D"] = self.filter_3d.detach().cpu().numpy().astype(np.float32)
        write_ply_vertices(path, cols)

    @classmethod
    def load_ply(cls, path, device=None) -> "Gaussians":
        """Read a PLY in the 3DGS layout (ours or any 3DGS-compatible tool's). Validates values."""
        cols = read_ply_vertices(path)
        required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                    "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
        missing = [c for c in required if c not in cols]
        if missing:
            raise PlyError(f"{path}: not a 3D Gaussian Splatting PLY: missing properties {missing}")
        n_rest = sum(1 for c in cols if c.startswith("f_rest_"))
        if any(f"f_rest_{i}" not in cols for i in range(n_rest)):
            raise PlyError(f"{path}: f_rest_* properties are not numbered 0..{n_rest - 1}")
        degree = {0: 0, 9: 1, 24: 2, 45: 3}.get(n_rest)
        if degree is None:
            raise PlyError(f"{path}: {n_rest} f_rest properties do not match an SH degree (0, 9, 24 or 45 expected)")
        f32 = lambda names: np.stack([cols[c].astype(np.float32) for c in names], axis=1)  # noqa: E731
        n = len(cols["x"])
        rest = f32([f"f_rest_{i}" for i in range(n_rest)]) if n_rest else np.zeros((n, 0), np.float32)
        rest = rest.reshape(n, 3, n_rest // 3).transpose(0, 2, 1)
        device = device or _default_device()
        t = lambda a: torch.tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)  # noqa: E731
        g = cls(
            means=t(f32(["x", "y", "z"])),
            quats=t(f32([f"rot_{i}" for i in range(4)])),
            log_scales=t(f32([f"scale_{i}" for i in range(3)])),
            opacity_logits=t(cols["opacity"].astype(np.float32)),
            sh_dc=t(f32(["f_dc_0", "f_dc_1", "f_dc_2"])),
            sh_rest=t(rest),
            max_sh_degree=degree,
            filter_3d=t(cols["filter_3D"].astype(np.float32)) if "filter_3D" in cols else None,
        )
        try:
            g.validate(where=str(path))
        except ModelError as e:
            raise PlyError(str(e)) from None
        return g
