"""Training a network ensemble in PyTorch (the ``skinloc[nets]`` extra).

Only training needs PyTorch: a trained ensemble is plain arrays (``ContactLocalizer.spec``)
that the network engine runs without it. ``import_torch`` is the one place that imports it,
on demand, so that the default path never does.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from skinloc._lazy import require_extra
from skinloc._typing import Points

__all__ = ["fit_network", "import_torch"]


def import_torch(purpose: str) -> Any:
    """``torch``, or a one-line error naming the extra that installs it.

    Only training networks needs PyTorch; the default model and every prediction run without
    it, so it is imported here, on demand, and never at module level.
    """
    return require_extra("torch", purpose)


def fit_network(
    model: Any,
    X: np.ndarray,
    y: Points,
    epochs: int,
    lr: float,
    progress: Callable[[int, int], None] | None,
) -> None:
    """Train ``model``'s ensemble with AdamW, cosine-decayed ``lr``, from its weights if any.

    ``model`` is a ``ContactLocalizer`` of kind network with its preprocessing attributes set;
    ``X (n, n_sensors)`` counts and ``y (n, 3)`` m. Sets ``coefs_``, ``intercepts_`` (each
    ``(n_members, in, out)`` / ``(n_members, 1, out)``) and ``loss_curve_``.
    """
    torch = import_torch(f"training the {model.config_['arch']!r} network")
    cfg = model.config_
    Z = (model._features(X, cfg) - model.feature_mean_) / model.feature_scale_
    T = (y - model.target_mean_) / model.target_scale_
    g = torch.Generator().manual_seed(int(model.random_state))
    E = cfg["n_members"]
    sizes = [Z.shape[1], *cfg["hidden"], 3]
    n_layers = len(sizes) - 1
    params: list[torch.Tensor] = []
    if hasattr(model, "coefs_"):
        for W, b in zip(model.coefs_, model.intercepts_, strict=True):
            params += [torch.tensor(W).requires_grad_(), torch.tensor(b).requires_grad_()]
    else:
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
            bound = 1.0 / np.sqrt(fan_in)  # the default init of torch.nn.Linear
            shape_w, shape_b = (E, fan_in, fan_out), (E, 1, fan_out)
            W = (torch.rand(shape_w, generator=g, dtype=torch.float64) * 2 - 1) * bound
            b = (torch.rand(shape_b, generator=g, dtype=torch.float64) * 2 - 1) * bound
            params += [W.requires_grad_(), b.requires_grad_()]
    act = {"relu": torch.relu, "tanh": torch.tanh, "gelu": torch.nn.functional.gelu}[
        cfg["activation"]
    ]
    Zt = torch.as_tensor(Z).expand(E, -1, -1)
    Tt = torch.as_tensor(T).expand(E, -1, -1)
    opt = torch.optim.AdamW(params, lr=lr, weight_decay=cfg["weight_decay"])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs)
    model.loss_curve_ = []
    for epoch in range(epochs):
        h = Zt
        if cfg["noise_std"] > 0:
            h = h + cfg["noise_std"] * torch.randn(h.shape, generator=g, dtype=h.dtype)
        for i in range(n_layers):
            h = torch.baddbmm(params[2 * i + 1], h, params[2 * i])
            if i < n_layers - 1:
                h = act(h)
        loss = ((h - Tt) ** 2).mean(dim=(1, 2)).sum()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        model.loss_curve_.append(loss.item() / E)
        if progress is not None and (epoch % 25 == 0 or epoch == epochs - 1):
            progress(epoch + 1, epochs)
    coefs = [params[2 * i].detach().numpy().copy() for i in range(n_layers)]
    intercepts = [params[2 * i + 1].detach().numpy().copy() for i in range(n_layers)]
    if not all(np.all(np.isfinite(w)) for w in coefs + intercepts):
        raise ValueError(
            "training diverged (non-finite weights); lower lr or check the input images"
        )
    model.coefs_, model.intercepts_ = coefs, intercepts
