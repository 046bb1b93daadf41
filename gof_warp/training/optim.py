"""Adam for the Gaussians, the position learning-rate schedule, and THE optimizer-state surgery.

One param group per raw parameter (``gaussians.params`` names), as 3DGS/GOF build it
(``scene/gaussian_model.py::training_setup``): Adam with ``eps = 1e-15``; learning rates

=============== =========================== ===============================================
parameter        learning rate               note
=============== =========================== ===============================================
means            1.6e-4·E → 1.6e-6·E         log-linear over 30 000 iterations, E = extent
sh_dc            2.5e-3
sh_rest          1.25e-4                     = 2.5e-3 / 20
opacity_logits   0.05
log_scales       5e-3
quats            1e-3
=============== =========================== ===============================================

(GOF_REFERENCE §4.) The appearance embedding/network rates (1e-3 each) are listed in
:class:`OptimConfig` for the trainer, which adds those groups itself.

Optimizer-state surgery (densification, pruning, opacity reset) happens in exactly one place,
:func:`replace_params`: it rebuilds each parameter tensor and moves Adam's ``exp_avg`` /
``exp_avg_sq`` rows with their Gaussians (kept rows keep their moments, appended rows start at zero,
reset rows are zeroed). The per-parameter ``step`` counter is shared by all rows and left alone, as
in 3DGS/GOF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ..core.devices import StreamWrappers, warp_device
from ..core.config import ConfigError
from ..core.errors import GofError
from ..core.model import PARAM_NAMES, Gaussians

ADAM_MOMENTS = ("exp_avg", "exp_avg_sq")
ADAM_KINDS = ("auto", "torch", "warp")


@dataclass
class OptimConfig:
    """Per-parameter learning rates and Adam settings (defaults: GOF ``arguments/__init__.py``)."""

    means_lr_init: float = 1.6e-4  # × scene extent
    means_lr_final: float = 1.6e-6  # × scene extent
    means_lr_delay_steps: int = field(default=0, metadata={"set_by": "experimental.means_lr_delay_steps"})  # 3DGS
    means_lr_delay_mult: float = field(default=0.01, metadata={"set_by": "experimental.means_lr_delay_mult"})
    means_lr_max_steps: int = 30_000  # the schedule reaches means_lr_final here
    sh_dc_lr: float = 2.5e-3  # learning rate of the SH DC colour
    sh_rest_lr: float = 2.5e-3 / 20.0  # learning rate of the higher SH coefficients
    opacity_lr: float = 0.05  # learning rate of the opacity logits
    scaling_lr: float = 5e-3  # learning rate of the log scales
    rotation_lr: float = 1e-3  # learning rate of the quaternions
    appearance_embedding_lr: float = 1e-3  # used by the trainer's appearance groups
    appearance_network_lr: float = 1e-3  # learning rate of the appearance network (appearance=true)
    eps: float = 1e-15  # Adam ε
    betas: tuple[float, float] = (0.9, 0.999)  # Adam β₁, β₂
    # torch's one-kernel Adam; None: on CUDA yes, on the CPU no (the loop version). Set from performance.adam
    fused: bool | None = field(default=None, metadata={"set_by": "performance.adam"})
    # the Gaussians' Adam: "torch" (torch's, fused as above), "warp" (WarpAdam: torch's fused CUDA arithmetic float for
    # float, one Warp kernel a parameter) or "auto": "warp" on CUDA, "torch" on the CPU. The appearance network's Adam
    # is always torch's. Set from performance.adam (training.settings.PerformanceConfig)
    adam: str = field(default="auto", metadata={"set_by": "performance.adam"})

    def __post_init__(self):
        if self.adam not in ADAM_KINDS:
            raise ConfigError(f"optim.adam (performance.adam) must be one of {ADAM_KINDS}, got {self.adam!r}")
        for name in ("means_lr_init", "means_lr_final", "sh_dc_lr", "sh_rest_lr", "opacity_lr", "scaling_lr",
                     "rotation_lr", "appearance_embedding_lr", "appearance_network_lr", "eps"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ConfigError(f"optim.{name} must be a finite number >= 0, got {v!r}")
        if isinstance(self.means_lr_max_steps, bool) or self.means_lr_max_steps < 1:
            raise ConfigError(f"optim.means_lr_max_steps must be an integer >= 1, got {self.means_lr_max_steps!r}")
        if self.means_lr_delay_steps < 0 or not 0 < self.means_lr_delay_mult <= 1:
            raise ConfigError("experimental.means_lr_delay_steps must be >= 0 and experimental.means_lr_delay_mult in "
                              f"(0, 1], got {self.means_lr_delay_steps}, {self.means_lr_delay_mult}")
        if len(tuple(self.betas)) != 2 or not all(0 <= b < 1 for b in self.betas):
            raise ConfigError(f"optim.betas must be two numbers in [0, 1), got {self.betas!r}")

    def adam_for(self, device) -> str:
        """The Gaussians' Adam on ``device``: ``"torch"`` or ``"warp"`` (``adam="auto"``: warp on CUDA)."""
        if self.adam != "auto":
            return self.adam
        return "warp" if torch.device(device).type == "cuda" else "torch"

    def adam_kwargs(self, device) -> dict:
        """``torch.optim.Adam`` keyword arguments for parameters on ``device`` (eps, betas, fused)."""
        fused = torch.device(device).type == "cuda" if self.fused is None else bool(self.fused)
        return {"eps": self.eps, "betas": tuple(self.betas), "fused": fused}

    def param_lr(self, name: str) -> float:
        """Constant learning rate of a non-position parameter."""
        return {"sh_dc": self.sh_dc_lr, "sh_rest": self.sh_rest_lr, "opacity_logits": self.opacity_lr,
                "log_scales": self.scaling_lr, "quats": self.rotation_lr}[name]


def position_lr(iteration: int, config: OptimConfig, extent: float) -> float:
    """Learning rate of the means at ``iteration`` (3DGS ``get_expon_lr_func``, scaled by ``extent``).

    Log-linear interpolation from ``means_lr_init·E`` at iteration 0 to ``means_lr_final·E`` at
    ``means_lr_max_steps`` (held afterwards); GOF's trainer counts iterations from 1 and calls this
    before each step. With ``means_lr_delay_steps > 0`` the rate is additionally ramped up by
    ``delay_mult + (1 − delay_mult)·sin(π/2 · clip(it/delay_steps))``.
    """
    lr_init, lr_final = config.means_lr_init * extent, config.means_lr_final * extent
    if iteration < 0 or (lr_init == 0.0 and lr_final == 0.0):
        return 0.0
    if config.means_lr_delay_steps > 0:
        ramp = math.sin(0.5 * math.pi * min(max(iteration / config.means_lr_delay_steps, 0.0), 1.0))
        delay = config.means_lr_delay_mult + (1.0 - config.means_lr_delay_mult) * ramp
    else:
        delay = 1.0
    t = min(max(iteration / config.means_lr_max_steps, 0.0), 1.0)
    return delay * math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


class LeanAdam(torch.optim.Adam):
    """``torch.optim.Adam`` whose fused step costs the host less: the same kernel (``torch._fused_adam_``), the same
    state and the same results bit for bit, with one ``_foreach_add_`` for every parameter's step counter and one
    fused call per group, instead of torch's per-group set-up (state checks, grouping by device and dtype, a counter
    update per group): for the Gaussians' six groups 0.16 ms of host time a step instead of 0.32 ms, the GPU's time
    unchanged (848k Gaussians on an H100 host).

    The lean path is taken for ``fused=True`` when every group is plain Adam (no AMSGrad, weight decay, maximize,
    capturable or differentiable mode, float learning rate and betas) and every parameter that has a gradient has its
    state; otherwise (the first step, which creates the state, a closure, any other option) torch's own ``step`` runs.
    Parameters without ``.grad`` are skipped, as torch does."""

    @torch.no_grad()
    def step(self, closure=None):
        if closure is not None or not self.defaults.get("fused"):
            return super().step(closure)
        calls, counters = [], []
        for group in self.param_groups:
            if (group["amsgrad"] or group["weight_decay"] or group["maximize"] or group["capturable"]
                    or group["differentiable"] or not isinstance(group["lr"], float)
                    or not all(isinstance(b, float) for b in group["betas"])):
                return super().step()
            params = [p for p in group["params"] if p.grad is not None]
            states = [self.state.get(p) for p in params]
            if any(not st for st in states) or any(p.grad.is_sparse for p in params):
                return super().step()
            if params:
                calls.append((group, params, states))
                counters += [st["step"] for st in states]
        if counters:
            torch._foreach_add_(counters, 1)
        for group, params, states in calls:
            beta1, beta2 = group["betas"]
            torch._fused_adam_(params, [p.grad for p in params], [st["exp_avg"] for st in states],
                               [st["exp_avg_sq"] for st in states], [], [st["step"] for st in states],
                               amsgrad=False, lr=group["lr"], beta1=beta1, beta2=beta2, weight_decay=0.0,
                               eps=group["eps"], maximize=False, grad_scale=None, found_inf=None)
        return None


class WarpAdam(torch.optim.Adam):
    """Adam (no weight decay) whose update of each parameter is one Warp kernel over its memory, four floats a thread
    (:func:`gof_warp.kernels.adam.adam_step`): parameter, gradient and both moments read once, parameter and moments
    written once, in 16-byte loads and stores. The kernel's arithmetic is that of torch's fused CUDA Adam, float for
    float (on a GPU the two give the same bits; torch's CPU Adam rounds differently). Its state is torch's unfused
    ``Adam``'s (``step`` a CPU tensor, ``exp_avg``, ``exp_avg_sq``), so :func:`replace_params`, ``state_dict`` and
    checkpoints treat it and torch's alike and either loads the other's state. Each parameter's launch is recorded once
    and replayed (only the gradient's address, the rate and the step count change between steps), so a step costs the
    host one replay per parameter; a new launch is recorded when the parameter or its moments are new tensors
    (densification).

    Parameters must be contiguous float32 tensors (the Gaussians' are); a parameter without ``.grad`` is skipped, as in
    torch. On CUDA the kernels run on torch's current stream. Options other than ``lr``, ``betas`` and ``eps`` are
    torch's defaults and not accepted."""

    def __init__(self, params, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        if not (lr >= 0.0 and math.isfinite(lr)):
            raise GofError(f"WarpAdam: lr must be a finite number >= 0, got {lr}")
        if not (eps >= 0.0 and math.isfinite(eps)):
            raise GofError(f"WarpAdam: eps must be a finite number >= 0, got {eps}")
        if len(betas) != 2 or not all(0.0 <= b < 1.0 for b in betas):
            raise GofError(f"WarpAdam: betas must be two numbers in [0, 1), got {betas}")
        super().__init__(params, lr=lr, betas=tuple(betas), eps=eps, foreach=False, fused=False)
        import warp as wp

        wp.init()  # idempotent; the arrays below need Warp's runtime
        self._launches: dict[tuple[int, int], dict] = {}  # (group, position) -> the recorded launch and its arrays
        self._streams = StreamWrappers()

    @torch.no_grad()
    def step(self, closure=None):
        """One Adam step of every parameter that has a gradient; ``closure`` (optional) re-evaluates the loss."""
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for gi, group in enumerate(self.param_groups):
            for pi, p in enumerate(group["params"]):
                if p.grad is None:
                    continue
                state = self._state_of(p)
                state["step"] += 1.0
                cmd = self._launch(gi, pi, p, state, group)
                cmd.set_param_at_index(3, float(group["lr"]))  # rounded to float32, as torch's fused kernel does
                cmd.set_param_at_index(7, float(state["step"]))
                cmd.launch(self._streams.launch_stream(p.device))
        return loss

    def _state_of(self, p: torch.Tensor) -> dict:
        grad = p.grad
        if p.dtype != torch.float32 or grad.dtype != torch.float32 or grad.is_sparse:
            raise GofError(f"WarpAdam takes dense float32 parameters and gradients, got {p.dtype} / {grad.dtype}")
        if not (p.is_contiguous() and grad.is_contiguous()) or grad.shape != p.shape:
            raise GofError(f"WarpAdam: parameter {list(p.shape)} and its gradient {list(grad.shape)} must be "
                           "contiguous and of one shape")
        state = self.state[p]
        if not state:
            state["step"] = torch.tensor(0.0)
            state["exp_avg"] = torch.zeros_like(p, memory_format=torch.contiguous_format)
            state["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.contiguous_format)
        if state["step"].device.type != "cpu":  # torch's fused Adam keeps it on the device: read once here
            state["step"] = state["step"].detach().to("cpu", torch.float32)
        if not (state["exp_avg"].is_contiguous() and state["exp_avg_sq"].is_contiguous()):
            raise GofError("WarpAdam: the Adam moments must be contiguous")
        return state

    def _launch(self, gi: int, pi: int, p: torch.Tensor, state: dict, group: dict):
        """The recorded launch of parameter ``pi`` of group ``gi`` with its gradient's address set: recorded anew when
        the parameter's or its moments' addresses, its size or the group's betas and eps changed. The launch holds
        addresses, not tensors: the caller's tensors keep the memory alive while it runs."""
        import warp as wp

        from ..kernels.adam import adam_step

        grad = p.grad
        moments = (state["exp_avg"], state["exp_avg_sq"])
        n = p.numel()
        key = (p.data_ptr(), *(t.data_ptr() for t in moments), n, tuple(group["betas"]), group["eps"])
        entry = self._launches.get((gi, pi))
        if entry is None or entry["key"] != key:
            device = warp_device(p.device)
            n4 = n // 4 if all(t.data_ptr() % 16 == 0 for t in (grad, p, *moments)) else 0  # vec4: 16-byte aligned
            views = [self._views(t, n4, device) for t in (grad, p, *moments)]
            beta1, beta2 = group["betas"]
            cmd = wp.launch(adam_step, dim=n4 + (n - 4 * n4), device=device, record_cmd=True,
                            inputs=[*views[0], n4, 0.0, float(beta1), float(beta2), float(group["eps"]), 1.0],
                            outputs=[views[1][0], views[2][0], views[3][0], views[1][1], views[2][1], views[3][1]])
            entry = self._launches[(gi, pi)] = {"key": key, "cmd": cmd, "n4": n4, "device": device,
                                                "grad": grad.data_ptr()}
        elif entry["grad"] != grad.data_ptr():  # a new gradient tensor: only its address changes
            g4, g1 = self._views(grad, entry["n4"], entry["device"])
            entry["cmd"].set_param_at_index(0, g4)
            entry["cmd"].set_param_at_index(1, g1)
            entry["grad"] = grad.data_ptr()
        if entry["n4"] and grad.data_ptr() % 16:  # torch allocates gradients aligned; a view of another tensor may not be
            raise GofError("WarpAdam: a gradient whose memory is not 16-byte aligned (a view into another tensor?)")
        return entry["cmd"]

    @staticmethod
    def _views(t: torch.Tensor, n4: int, device: str) -> tuple:
        """``(vec4 view of the first 4·n4 floats, flat float view)`` of ``t``'s memory (no reference to ``t`` kept)."""
        import warp as wp

        vec4 = (wp.array(ptr=t.data_ptr(), dtype=wp.vec4, shape=(n4,), device=device) if n4
                else wp.empty(0, dtype=wp.vec4, device=device))
        return vec4, wp.array(ptr=t.data_ptr(), dtype=wp.float32, shape=(t.numel(),), device=device)


def make_optimizer(gaussians: Gaussians, config: OptimConfig, extent: float) -> torch.optim.Adam:
    """Adam (:class:`WarpAdam` where ``config.adam_for`` the Gaussians' device says ``"warp"``, by default on CUDA;
    else :class:`LeanAdam`) with one group per raw parameter, each group tagged ``"name"``.

    Makes the parameters leaf tensors that require grad (``gaussians.requires_grad_(True)``) when they
    are not already. ``extent`` scales the means' rate (see :func:`position_lr`).
    """
    if not (extent > 0 and math.isfinite(extent)):
        raise GofError(f"make_optimizer: extent must be a positive finite number, got {extent}")
    if not all(p.is_leaf and p.requires_grad for p in gaussians.params.values()):
        gaussians.requires_grad_(True)
    groups = []
    for name in PARAM_NAMES:
        lr = position_lr(0, config, extent) if name == "means" else config.param_lr(name)
        groups.append({"params": [gaussians.params[name]], "lr": lr, "name": name})
    if config.adam_for(gaussians.device) == "warp":
        return WarpAdam(groups, lr=0.0, betas=tuple(config.betas), eps=config.eps)
    return LeanAdam(groups, lr=0.0, **config.adam_kwargs(gaussians.device))


def update_learning_rate(optimizer: torch.optim.Optimizer, iteration: int, config: OptimConfig, extent: float) -> float:
    """Set the means group's rate for ``iteration``; returns it."""
    lr = position_lr(iteration, config, extent)
    _group(optimizer, "means")["lr"] = lr
    return lr


def _group(optimizer: torch.optim.Optimizer, name: str) -> dict:
    for g in optimizer.param_groups:
        if g.get("name") == name:
            if len(g["params"]) != 1:
                raise GofError(f"optimizer group {name!r} must hold exactly one tensor, has {len(g['params'])}")
            return g
    raise GofError(f"optimizer has no param group named {name!r} (build it with make_optimizer)")


def _as_index(sel, n: int, what: str, device) -> torch.Tensor:
    """A boolean mask [n] or an integer index → int64 index tensor."""
    sel = torch.as_tensor(sel, device=device)
    if sel.dtype == torch.bool:
        if sel.shape != (n,):
            raise GofError(f"{what}: boolean mask must have shape [{n}], got {list(sel.shape)}")
        return torch.nonzero(sel).flatten()
    if sel.dtype not in (torch.int32, torch.int64) or sel.ndim != 1:
        raise GofError(f"{what}: expected a bool mask or a 1-D integer index, got {sel.dtype} {list(sel.shape)}")
    sel = sel.long()
    if sel.numel() and (int(sel.min()) < 0 or int(sel.max()) >= n):
        raise GofError(f"{what}: index out of range [0, {n})")
    return sel


def replace_params(gaussians: Gaussians, optimizer: torch.optim.Optimizer | None, *, keep=None,
                   append: dict | None = None, reset: dict | None = None) -> None:
    """The one place where Gaussians are added, removed or reset together with Adam's state.

    Applied in this order, in place on ``gaussians`` (and ``optimizer`` when given):

    1. ``keep``: bool mask ``[N]`` or int index ``[K]`` — rows kept (in index order); their Adam
       moments are kept with them. ``None`` keeps all.
    2. ``append``: dict with every name of ``PARAM_NAMES`` → new rows ``[M, ...]`` (raw values),
       appended after the kept rows; their moments start at zero. When ``gaussians.filter_3d`` is set,
       ``append["filter_3d"]`` (``[M]``) is required too (the trainer recomputes the filter after
       densifying, as GOF does; children usually carry their parent's value until then).
    3. ``reset``: dict name → ``(rows, values)``: rows (bool mask / index over the rows after steps 1–2)
       of that parameter get ``values`` (broadcastable to ``[len(rows), ...]``) and zero moments.

    The new tensors are fresh leaves (``requires_grad`` as before) with no ``.grad``; the optimizer's
    groups point to them and its state is re-keyed. Other groups (appearance) are untouched.
    """
    n = len(gaussians)
    device = gaussians.device
    keep_idx = None if keep is None else _as_index(keep, n, "replace_params keep", device)
    if append is not None:
        missing = [k for k in PARAM_NAMES if k not in append]
        if missing:
            raise GofError(f"replace_params append: missing parameters {missing}")
        if gaussians.filter_3d is not None and "filter_3d" not in append:
            raise GofError("replace_params append: the Gaussians carry a 3D filter; append['filter_3d'] is required")
        m = append["means"].shape[0]
        for k in PARAM_NAMES:
            want = (m, *gaussians.params[k].shape[1:])
            if tuple(append[k].shape) != want:
                raise GofError(f"replace_params append[{k!r}]: expected shape {list(want)}, "
                               f"got {list(append[k].shape)}")
    reset = reset or {}
    unknown = [k for k in reset if k not in PARAM_NAMES]
    if unknown:
        raise GofError(f"replace_params reset: unknown parameters {unknown} (known: {list(PARAM_NAMES)})")
    n_after = (n if keep_idx is None else keep_idx.numel()) + (0 if append is None else append["means"].shape[0])
    reset_idx = {k: (_as_index(rows, n_after, f"replace_params reset[{k!r}]", device), vals)
                 for k, (rows, vals) in reset.items()}

    def rebuild(t: torch.Tensor, new_rows) -> torch.Tensor:
        t = t if keep_idx is None else t[keep_idx]
        return t if new_rows is None else torch.cat([t, new_rows.to(t.dtype)], dim=0)

    with torch.no_grad():
        for name in PARAM_NAMES:
            old = gaussians.params[name]
            new = rebuild(old.detach(), None if append is None else append[name])
            zero_rows = None
            if name in reset_idx:
                rows, vals = reset_idx[name]
                new = new.clone() if keep_idx is None and append is None else new
                new[rows] = torch.as_tensor(vals, dtype=new.dtype, device=new.device)
                zero_rows = rows
            new = new.contiguous().requires_grad_(old.requires_grad)
            gaussians.params[name] = new
            if optimizer is None:
                continue
            group = _group(optimizer, name)
            if group["params"][0] is not old:
                raise GofError(f"optimizer group {name!r} does not hold gaussians.params[{name!r}] (stale optimizer?)")
            state = optimizer.state.pop(old, None)
            group["params"][0] = new
            if state is None:
                continue
            for key in ADAM_MOMENTS:
                if key in state:
                    z = None if append is None else torch.zeros_like(append[name], dtype=state[key].dtype)
                    moment = rebuild(state[key], z)
                    if zero_rows is not None:
                        moment = moment.clone() if keep_idx is None and append is None else moment
                        moment[zero_rows] = 0.0
                    state[key] = moment
            optimizer.state[new] = state
        if gaussians.filter_3d is not None:
            gaussians.filter_3d = rebuild(gaussians.filter_3d, None if append is None else append["filter_3d"])


def check_optimizer_state(gaussians: Gaussians, optimizer: torch.optim.Optimizer) -> None:
    """Raise :class:`GofError` unless every group holds the current parameter and its moments match its shape."""
    for name in PARAM_NAMES:
        p = gaussians.params[name]
        if _group(optimizer, name)["params"][0] is not p:
            raise GofError(f"optimizer group {name!r} does not hold the current gaussians.params[{name!r}]")
        state = optimizer.state.get(p, {})
        for key in ADAM_MOMENTS:
            if key in state and state[key].shape != p.shape:
                raise GofError(f"Adam {key} of {name!r} has shape {list(state[key].shape)}, parameter {list(p.shape)}")
