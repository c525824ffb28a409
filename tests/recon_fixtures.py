"""Stage 0 test cases shared by tests/test_recon.py and the gsplat golden recorder
(tests/golden/record_oracles.py): random surfels and the constructed densify / prune case."""
from __future__ import annotations

import math

import torch

from gspi.gaussians.model import Gaussians2D
from gspi.recon.strategy import make_strategy, to_params

STRATEGY_CFG = dict(refine_start_iter=100, refine_stop_iter=1000, refine_every=100, reset_every=500,
                    grow_grad2d=2e-4, grow_scale3d=0.01, prune_opa=0.005, prune_scale3d=0.1)


def random_surfels(n: int, seed: int = 0, dtype=torch.float32) -> Gaussians2D:
    gen = torch.Generator().manual_seed(seed)
    g = Gaussians2D.empty(n, 3, dtype=dtype)
    g.means = (torch.rand(n, 3, generator=gen, dtype=dtype) - 0.5) * 1.2
    g.quats = torch.randn(n, 4, generator=gen, dtype=dtype)
    g.log_scales = torch.full((n, 2), -2.5, dtype=dtype) + 0.3 * torch.randn(n, 2, generator=gen, dtype=dtype)
    g.opacity_logits = torch.randn(n, generator=gen, dtype=dtype)
    g.sh_dc = torch.randn(n, 1, 3, generator=gen, dtype=dtype)
    g.sh_rest = 0.1 * torch.randn(n, 15, 3, generator=gen, dtype=dtype)
    return g


def densify_case():
    """10 surfels: 0-3 small (scale 0.0025), 4-9 large (0.135); high screen gradient on 0, 1, 4, 5;
    opacity 0.001 on 2 and 6 (pruned)."""
    n = 10
    g = random_surfels(n)
    g.log_scales = torch.tensor([[-6.0, -6.0]] * 4 + [[-2.0, -2.0]] * 6)
    g.opacity_logits = torch.full((n,), 2.0)
    g.opacity_logits[[2, 6]] = math.log(0.001 / 0.999)
    params = to_params(g)
    optimizers = {k: torch.optim.Adam([{"params": [p], "lr": 1e-3, "name": k}], eps=1e-15)
                  for k, p in params.items()}
    for p in params.values():
        p.grad = torch.full_like(p, 0.01)
    for opt in optimizers.values():
        opt.step()
        opt.zero_grad(set_to_none=True)
    grad = torch.full((1, n, 2), 1e-6)
    grad[0, [0, 1, 4, 5]] = 1e-3
    densify = torch.zeros(1, n, 2, requires_grad=True)
    densify.grad = grad
    info = {"gradient_2dgs": densify, "radii": torch.ones(1, n, 2, dtype=torch.int32), "width": 2, "height": 2,
            "n_cameras": 1, "gaussian_ids": None}
    return params, optimizers, info


def densify_step(impl: str) -> tuple[dict, dict]:
    """(params, optimizers) after one refine step (iteration 200) of ``impl``'s strategy on
    :func:`densify_case`: what tests/golden/gsplat_densify.json records for gsplat."""
    strategy, _ = make_strategy(STRATEGY_CFG, impl)
    params, optimizers, info = densify_case()
    state = strategy.initialize_state(scene_scale=1.0)
    strategy.step_pre_backward(params, optimizers, state, 200, info)
    torch.manual_seed(0)
    strategy.step_post_backward(params, optimizers, state, 200, info, packed=False)
    return params, optimizers
