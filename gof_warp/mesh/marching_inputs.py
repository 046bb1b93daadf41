"""What marching (:mod:`gof_warp.mesh.marching`) takes in: points, values and tetrahedra as numpy, torch or
``wp.array``, and the field as host code or a Warp field function — without importing torch.

Torch is used only when the caller's data is torch (a tensor, or ``field_input="torch"``): the tests
``isinstance(x, torch.Tensor)`` go through ``sys.modules``, so a pure Warp program never loads it.

Field evaluators (one interface, ``evaluator(x: wp.array(vec3) [M], what) -> wp.array(float32) [M]``):

* :class:`FieldCaller`: the user's callable on numpy / torch / Warp points (host code, any cost);
* :class:`WarpField`: the user's ``@wp.func`` through
  :func:`gof_warp.kernels.marching_tets.make_field_kernel` — one launch, nothing copied to the host.
"""

from __future__ import annotations

from typing import Callable, Union

import numpy as np
import warp as wp

from ..core.errors import GofError
from ..core.streams import loaded_torch, torch_stream  # noqa: F401 - part of this module's interface
from ..kernels import marching_tets as mt

FIELD_KINDS = ("numpy", "torch", "warp")

Field = Union[Callable[[object], object], wp.Function]


def is_torch(x) -> bool:
    torch = loaded_torch()
    return torch is not None and isinstance(x, torch.Tensor)


def resolve_device(device) -> str:
    """Warp's name for ``device``. With torch loaded: :mod:`gof_warp.core.devices`' rule (torch and Warp agree);
    without: Warp's own (None or ``"auto"`` → the current device, so ``wp.ScopedDevice`` is respected)."""
    if loaded_torch() is not None:
        from ..core.devices import warp_device

        return warp_device(None if device is None else str(device))
    if device is None or str(device) == "auto":
        return str(wp.get_device())
    try:
        return str(wp.get_device(str(device)))
    except (RuntimeError, ValueError) as err:
        raise GofError(f"device {device!r} is not a Warp device here: {err}") from err


def field_kind(points) -> str:
    if is_torch(points):
        return "torch"
    if isinstance(points, wp.array):
        return "warp"
    return "numpy"



# ---------------------------------------------------------------------------------------------- inputs
def as_vec3_array(x, name: str, device: str) -> wp.array:
    """``[N, 3]`` numpy / torch / ``wp.array(vec3)`` → ``wp.array(vec3)`` on ``device`` (checked finite)."""
    if isinstance(x, wp.array):
        if x.dtype == wp.vec3 and x.ndim == 1:
            return x.to(device)
        if x.dtype == wp.float32 and x.ndim == 2 and x.shape[1] == 3:
            return wp.array(ptr=x.ptr, dtype=wp.vec3, shape=x.shape[0], device=x.device, copy=False).to(device)
        raise GofError(f"{name} must be a wp.array of vec3 or float32 [N, 3], got {x.dtype} {x.shape}")
    if not is_torch(x):
        a = np.asarray(x)
        if a.ndim != 2 or a.shape[1] != 3:
            raise GofError(f"{name} must have shape [N, 3], got {tuple(a.shape)}")
        if not np.issubdtype(a.dtype, np.floating):
            raise GofError(f"{name} must be floating point, got {a.dtype}")
        if a.size and not np.isfinite(a).all():
            raise GofError(f"{name} has NaN/inf entries")
        return wp.array(np.ascontiguousarray(a, dtype=np.float32), dtype=wp.vec3, device=device)
    torch = loaded_torch()
    t = x.detach()
    if t.ndim != 2 or t.shape[1] != 3:
        raise GofError(f"{name} must have shape [N, 3], got {tuple(t.shape)}")
    if not t.is_floating_point():
        raise GofError(f"{name} must be floating point, got {t.dtype}")
    if t.numel() and not bool(torch.isfinite(t).all()):
        raise GofError(f"{name} has NaN/inf entries")
    if t.shape[0] == 0:  # wp.from_torch rejects empty [0, 3] tensors (strides)
        return wp.empty(0, dtype=wp.vec3, device=device)
    t = t.to(device=wp.device_to_torch(device), dtype=torch.float32).contiguous()
    return wp.from_torch(t, dtype=wp.vec3)


def as_float_array(x, n: int, name: str, device: str) -> wp.array:
    """``[n]`` (or ``[n, 1]``) values → ``wp.array(float32)`` on ``device`` (checked finite)."""
    if isinstance(x, wp.array):
        if x.dtype == wp.float32 and x.size == n and (x.ndim == 1 or x.shape[0] == n) and x.is_contiguous:
            flat = x if x.ndim == 1 else x.flatten()
            return check_finite(flat.to(device), name)
        x = x.numpy()
    if not is_torch(x):
        a = np.asarray(x)
        if a.size != n or (a.ndim > 1 and a.shape[0] != n):
            raise GofError(f"{name} must have {n} values (shape [{n}]), got shape {tuple(a.shape)}")
        a = np.ascontiguousarray(a.reshape(-1), dtype=np.float32)
        bad = int((~np.isfinite(a)).sum())
        if bad:
            raise GofError(f"{name} has {bad} NaN/inf values")
        return wp.array(a, dtype=wp.float32, device=device)
    torch = loaded_torch()
    t = x.detach()
    if t.numel() != n or (t.ndim > 1 and t.shape[0] != n):
        raise GofError(f"{name} must have {n} values (shape [{n}]), got shape {tuple(t.shape)}")
    t = t.reshape(-1)
    if not t.is_floating_point():
        t = t.float()
    bad = int((~torch.isfinite(t)).sum()) if n else 0
    if bad:
        raise GofError(f"{name} has {bad} NaN/inf values")
    if n == 0:
        return wp.empty(0, dtype=wp.float32, device=device)
    t = t.to(device=wp.device_to_torch(device), dtype=torch.float32).contiguous()
    return wp.from_torch(t, dtype=wp.float32)


def check_finite(values: wp.array, name: str) -> wp.array:
    """``values`` (float32 on the device) after a device-side count of NaN/inf (one int read back)."""
    if values.shape[0]:
        bad = wp.zeros(1, dtype=wp.int32, device=values.device)
        wp.launch(mt.count_nonfinite, dim=values.shape[0], inputs=[values], outputs=[bad], device=values.device)
        n_bad = int(bad.numpy()[0])
        if n_bad:
            raise GofError(f"{name} has {n_bad} NaN/inf values")
    return values


class TetSource:
    """Tetrahedra ``[T, 4]`` (numpy / torch / ``wp.array``) served as device chunks of ``wp.vec4i``."""

    def __init__(self, tets, n_points: int, device: str):
        self.device = device
        if isinstance(tets, wp.array):  # trusted (documented): no index check on device arrays
            if tets.dtype == wp.int32 and tets.ndim == 2 and tets.shape[1] == 4:
                tets = wp.array(ptr=tets.ptr, dtype=wp.vec4i, shape=tets.shape[0], device=tets.device, copy=False)
            elif tets.dtype != wp.vec4i:
                raise GofError(f"tets must be a wp.array of vec4i or int32 [T, 4], got {tets.dtype}")
            self.data, self.count = tets.to(device), tets.shape[0]
            return
        t = tets.detach() if is_torch(tets) else np.asarray(tets)
        if t.ndim != 2 or t.shape[1] != 4:
            raise GofError(f"tets must have shape [T, 4], got {tuple(t.shape)}")
        if is_torch(t):
            if t.is_floating_point() or t.dtype == loaded_torch().bool:
                raise GofError(f"tets must hold integer point indices, got {t.dtype}")
        elif not np.issubdtype(t.dtype, np.integer):
            raise GofError(f"tets must hold integer point indices, got {t.dtype}")
        if t.shape[0] and (int(t.min()) < 0 or int(t.max()) >= n_points):
            raise GofError(f"tets index points outside [0, {n_points}) (min {int(t.min())}, max {int(t.max())})")
        self.data, self.count = t, t.shape[0]

    def chunk(self, start: int, end: int) -> wp.array:
        d = self.data[start:end]
        if isinstance(d, wp.array):
            return d
        if is_torch(d):
            d = d.to(device=wp.device_to_torch(self.device), dtype=loaded_torch().int32).contiguous()
            return wp.from_torch(d, dtype=wp.vec4i)
        return wp.array(np.ascontiguousarray(d, dtype=np.int32), dtype=wp.vec4i, device=self.device)


def check_levels(levels) -> list[float]:
    lv = [float(x) for x in np.atleast_1d(np.asarray(levels, dtype=np.float64))]
    if not lv or not all(np.isfinite(lv)):
        raise GofError(f"levels must be a non-empty list of finite numbers, got {levels!r}")
    return lv


StepsPerCall = Union[int, Callable[[int, int], int]]  # search steps per field call, or f(edges, steps done)
MAX_STEPS_PER_CALL = 12  # 4,095 field points per edge and call


def check_steps_per_call(d) -> int:
    if isinstance(d, bool) or not isinstance(d, (int, np.integer)) or d < 1 or d > MAX_STEPS_PER_CALL:
        raise GofError(f"steps_per_call must be an integer in [1, {MAX_STEPS_PER_CALL}], got {d!r}")
    return int(d)


# each bisection step halves the bracket around a vertex: past 24 (float32's significand bits) it is below the
# coordinates' precision and a step only costs a field call
MAX_BINARY_STEPS = 24


def check_steps(binary_steps) -> int:
    if int(binary_steps) != binary_steps or not 0 <= binary_steps <= MAX_BINARY_STEPS:
        raise GofError(f"binary_steps must be an integer in [0, {MAX_BINARY_STEPS}] (each step halves the bracket; "
                       f"float32 has 24 significand bits), got {binary_steps!r}")
    return int(binary_steps)


# ---------------------------------------------------------------------------------------------- field
class FieldCaller:
    """Calls the user's field on a ``wp.array(vec3)`` in the chosen kind and returns ``wp.array(float32)``."""

    def __init__(self, field: Field, kind: str, device: str):
        if not callable(field):
            raise GofError(f"field must be callable or a @wp.func, got {type(field).__name__}")
        if kind not in FIELD_KINDS:
            raise GofError(f"field_input must be one of {FIELD_KINDS}, got {kind!r}")
        if kind == "torch":
            import torch  # noqa: F401  (the caller asked for torch tensors)
        self.field, self.kind, self.device = field, kind, device

    def __call__(self, x: wp.array, what: str) -> wp.array:
        n = x.shape[0]
        if self.kind == "numpy":
            arg = x.numpy().reshape(n, 3)
        elif self.kind == "torch":
            arg = wp.to_torch(x).reshape(n, 3)
        else:
            arg = x
        out = self.field(arg)
        return as_float_array(out, n, f"field values ({what})", self.device)


class WarpField:
    """Evaluates a user's ``@wp.func`` field on the device: one launch of its kernel per batch, no host copy."""

    def __init__(self, field: wp.Function, params, device: str):
        try:
            params_type = mt.field_params_type(field)
        except TypeError as err:
            raise GofError(str(err)) from err
        if (params_type is None) != (params is None):
            need = "takes no params: leave field_params None" if params_type is None else f"needs field_params of type {params_type}"
            raise GofError(f"field function {field.key} {need}")
        self.kernel = mt.make_field_kernel(field)
        self.params, self.device = params, device

    def __call__(self, x: wp.array, what: str = "") -> wp.array:
        values = wp.empty(x.shape[0], dtype=wp.float32, device=self.device)
        inputs = [x] if self.params is None else [x, self.params]
        wp.launch(self.kernel, dim=x.shape[0], inputs=inputs, outputs=[values], device=self.device)
        return values


def make_field(field, params, kind: str, device: str):
    """The batch evaluator of ``field``: ``WarpField`` for a ``@wp.func``, else ``FieldCaller``."""
    if isinstance(field, wp.Function):
        return WarpField(field, params, device)
    if params is not None:
        raise GofError("field_params is only for a Warp field function (@wp.func)")
    return FieldCaller(field, kind, device)
