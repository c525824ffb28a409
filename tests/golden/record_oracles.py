"""Record the outputs of the three reference packages the tests compare against, once, as goldens.

diffusers (the DDIM schedule oracle of tests/test_stage2_schedule.py), the original LPIPS
package (richzhang/PerceptualSimilarity, the oracle of tests/test_lpips_net.py) and gsplat's
densify strategy (the oracle of the builtin port, tests/test_recon.py) are not part of
the default install, so `make test` could never run them. This script runs the real packages once
and writes what they return to tests/golden/diffusers_ddim.json, lpips_package.json and gsplat_densify.json,
which the tests read on every commit. Regenerate only on purpose (a new fixture or a new version).

Run from the repository root with the packages on a throwaway path (never the project's venv)::

    # --no-deps where a dependency would bring its own torch/numpy over the venv's
    python -m pip install --target /tmp/oracle --no-deps diffusers lpips safetensors regex torchvision
    python -m pip install --target /tmp/oracle huggingface_hub
    PYTHONPATH=/tmp/oracle:. python -m tests.golden.record_oracles
    # gsplat's densify strategy is plain torch: it runs on the CPU without its CUDA kernels
    python -m pip install --target /tmp/gsplat --no-deps gsplat==1.5.3
    PYTHONPATH=/tmp/gsplat:. python -m tests.golden.record_oracles gsplat_densify.json

(recorded with diffusers 0.42.1, lpips 0.1.4, torchvision 0.29.1 on torch 2.13.0+cpu; the
versions are written into each golden's ``producer``)

lpips needs torchvision only for the AlexNet module layout (``pnet_rand=True`` downloads nothing,
and our converted weights are loaded into it). A torchvision built for a newer torch fails to
register its C ops; AlexNet uses none of them, so :func:`_import_torchvision_without_ops` skips them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import torch

GOLDEN = Path(__file__).parent
DIFFUSERS_JSON = GOLDEN / "diffusers_ddim.json"
LPIPS_JSON = GOLDEN / "lpips_package.json"
GSPLAT_JSON = GOLDEN / "gsplat_densify.json"


def _import_torchvision_without_ops() -> None:
    """Import torchvision with its compiled ops disabled (AlexNet is plain torch.nn)."""
    def _skip(*args, **kwargs):
        raise OSError("torchvision C ops skipped: not needed by AlexNet")

    register_fake = torch.library.register_fake
    torch.ops.load_library = _skip
    torch.library.register_fake = lambda op, *a, **k: ((lambda fn: fn) if str(op).startswith("torchvision::")
                                                        else register_fake(op, *a, **k))
    import torchvision  # noqa: F401
    torch.library.register_fake = register_fake


def record_diffusers() -> dict:
    import diffusers

    from tests.oracle_fixtures import (FULL_LOOP_CASES, NUM_STEPS_CASES, AffineEpsModel, add_noise_inputs,
                                             full_loop_noise, make_f0, make_inputs)

    def make_ddim(clip_sample=True):
        return diffusers.DDIMScheduler(num_train_timesteps=1000, beta_schedule="squaredcos_cap_v2",
                                       timestep_spacing="trailing", clip_sample=clip_sample)

    out = {"producer": {"diffusers": diffusers.__version__, "torch": torch.__version__,
                        "script": "tests/golden/record_oracles.py"},
           "scheduler": "DDIMScheduler(num_train_timesteps=1000, beta_schedule='squaredcos_cap_v2', "
                        "timestep_spacing='trailing')",
           "alphas_cumprod": make_ddim().alphas_cumprod.tolist(), "timesteps": {}, "full_loop": {}}
    for n in NUM_STEPS_CASES:
        sched = make_ddim()
        sched.set_timesteps(n)
        out["timesteps"][str(n)] = sched.timesteps.tolist()
    f0, eps, t = add_noise_inputs()
    out["add_noise"] = {"t": t.tolist(), "f_t": make_ddim().add_noise(f0, eps, t).tolist()}
    for key, (clip_sample, use_clipped, eta) in FULL_LOOP_CASES.items():
        sched = make_ddim(clip_sample)
        sched.set_timesteps(50)
        model, f0 = AffineEpsModel(), make_f0().float()
        inputs = make_inputs(f0)
        g_ref, sample = full_loop_noise(f0)
        for step in sched.timesteps:
            eps = model(sample, step.expand(f0.shape[0]), inputs).eps
            sample = sched.step(eps, step, sample, eta=eta, use_clipped_model_output=use_clipped,
                                generator=g_ref).prev_sample
        out["full_loop"][key] = sample.tolist()
    return out


def record_lpips() -> dict:
    _import_torchvision_without_ops()
    import lpips

    from eval.lpips.net import load_lpips
    from tests.oracle_fixtures import SPATIAL_STRIDE, lpips_inputs, state_dict_sha256, summarize_spatial

    ref = lpips.LPIPS(net="alex", version="0.1", pnet_rand=True, verbose=False).eval()
    # lpips 0.1.4 also lists lin0..lin4 as ``lins.0..4`` (the same modules): only those may be missing
    missing, unexpected = ref.load_state_dict(load_lpips().state_dict(), strict=False)
    assert not unexpected and all(k.startswith("lins.") for k in missing), (missing, unexpected)
    x, y = lpips_inputs()
    with torch.no_grad():
        non_spatial = ref(x, y)
        ref.spatial = True
        spatial = ref(x, y)
    from importlib.metadata import version

    return {"producer": {"lpips": f"{version('lpips')} (richzhang/PerceptualSimilarity)",
                         "torchvision": version("torchvision"), "torch": torch.__version__,
                         "net": "alex", "version": "0.1", "script": "tests/golden/record_oracles.py",
                         "weights_sha256": state_dict_sha256(ref.state_dict())},
            "note": "lpips.LPIPS(pnet_rand=True) with eval.lpips.weights' converted weights loaded: "
                    "checks our forward pass against the original code",
            "non_spatial": non_spatial.flatten().tolist(),
            "spatial": summarize_spatial(spatial), "spatial_stride": SPATIAL_STRIDE}


def record_gsplat_densify() -> dict:
    """gsplat's DefaultStrategy on tests/recon_fixtures.densify_case (the builtin port's oracle)."""
    from importlib.metadata import version

    from tests.recon_fixtures import densify_step

    params, optimizers = densify_step("gsplat")
    return {"producer": {"gsplat": version("gsplat"), "torch": torch.__version__},
            "case": "tests/recon_fixtures.densify_step('gsplat'): one refine step at iteration 200",
            "params": {k: p.detach().tolist() for k, p in params.items()},
            "exp_avg_sq": {k: optimizers[k].state[p]["exp_avg_sq"].tolist() for k, p in params.items()}}


def main() -> None:
    only = set(sys.argv[1:])  # e.g. gsplat_densify.json: record one golden
    for path, record in ((DIFFUSERS_JSON, record_diffusers), (LPIPS_JSON, record_lpips),
                         (GSPLAT_JSON, record_gsplat_densify)):
        if only and path.name not in only:
            continue
        path.write_text(json.dumps(record(), indent=1) + "\n")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
