import pytest
import torch

from experiments.known_light.shrink_checkpoint import ROUGHNESS, with_correction_scale
from experiments.known_light.tests.test_gate_checkpoint import tiny_checkpoint
from gspi.stage2.checkpoint import CheckpointError
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import RCWConfig, RCWDenoiser


def model_of(ckpt: dict) -> RCWDenoiser:
    model = RCWDenoiser(RCWConfig(**ckpt["rcw_config"]))
    model.load_state_dict(ckpt["ema"])
    return model.eval()


def test_the_roughness_correction_is_scaled_and_the_rest_kept():
    torch.manual_seed(0)
    ckpt = tiny_checkpoint("x0_readout")
    for name in ("out.weight", "out.bias"):  # a trained head: zero at init otherwise
        ckpt["ema"][name] = torch.randn_like(ckpt["ema"][name])
    out = with_correction_scale(ckpt, 0.25)
    assert out["config"]["readout_correction_scale"] == {"channel": ROUGHNESS, "scale": 0.25}
    full, shrunk = model_of(ckpt), model_of(out)
    n = 9
    inputs = Stage2Inputs(xyz=torch.rand(1, n, 3), local_cond=torch.rand(1, n, 42))
    f_t = torch.randn(1, n, 5)
    with torch.no_grad():
        head, _ = full.head(f_t, torch.tensor([3]), inputs)
        x0_full = full.x0_of_head(head, inputs)
        head_s, _ = shrunk.head(f_t, torch.tensor([3]), inputs)
        x0_shrunk = shrunk.x0_of_head(head_s, inputs)
    readout = full.x0_of_head(torch.zeros_like(head), inputs)  # the read-out alone (scale 0)
    expected = readout + 0.25 * (x0_full - readout)
    assert torch.allclose(x0_shrunk[..., ROUGHNESS], expected[..., ROUGHNESS], atol=1e-5)
    others = [c for c in range(5) if c != ROUGHNESS]
    assert torch.allclose(x0_shrunk[..., others], x0_full[..., others], atol=1e-6)
    assert not torch.allclose(x0_full[..., ROUGHNESS], readout[..., ROUGHNESS])  # the test could fail


def test_a_model_without_the_readout_head_or_a_scale_outside_0_1_is_refused():
    with pytest.raises(CheckpointError, match="x0_readout head's correction"):
        with_correction_scale(tiny_checkpoint("x0"), 0.5, "m.pt")
    with pytest.raises(ValueError, match="between 0 and 1"):
        with_correction_scale(tiny_checkpoint("x0_readout"), 1.5)
