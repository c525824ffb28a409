"""gspi.stage2.readout_correction: an x0_readout head's correction scaled per channel after training."""
from __future__ import annotations

import pytest
import torch

from gspi.stage2.checkpoint import CheckpointError, rcw_config_dict
from gspi.stage2.inputs import Stage2Inputs
from gspi.stage2.model import RCWConfig, RCWDenoiser
from gspi.stage2.readout_correction import CHANNELS, scale_readout_correction

LOCAL = 42  # local condition width: the read-out's columns start at 35


def trained_checkpoint(prediction: str = "x0_readout") -> dict:
    """A tiny model whose head is not zero (it is at init: the untrained model is the read-out)."""
    torch.manual_seed(0)
    rcw = RCWConfig(num_latents=4, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1, num_heads=2,
                    local_cond_dim=LOCAL, global_token_dim=0, prediction=prediction,
                    readout_column=35 if prediction == "x0_readout" else None)
    state = RCWDenoiser(rcw).state_dict()
    for name in ("out.weight", "out.bias"):
        state[name] = torch.randn_like(state[name])
    return {"format": "gspi-stage2", "version": 1, "step": 7, "rcw_config": rcw_config_dict(rcw),
            "config": {"seed": 0}, "ema": state, "model": state}


def clean_estimate(ckpt: dict, inputs: Stage2Inputs, f_t: torch.Tensor, zero_head: bool = False) -> torch.Tensor:
    model = RCWDenoiser(RCWConfig(**ckpt["rcw_config"]))
    model.load_state_dict(ckpt["ema"])
    with torch.no_grad():
        head, _ = model.eval().head(f_t, torch.tensor([3]), inputs)
        return model.x0_of_head(torch.zeros_like(head) if zero_head else head, inputs)


def test_each_named_channel_keeps_its_fraction_of_the_correction_and_the_rest_is_as_trained():
    ckpt = trained_checkpoint()
    n = 11
    inputs = Stage2Inputs(xyz=torch.rand(1, n, 3), local_cond=torch.rand(1, n, LOCAL))
    f_t = torch.randn(1, n, 5)
    prior = clean_estimate(ckpt, inputs, f_t)
    readout = clean_estimate(ckpt, inputs, f_t, zero_head=True)
    assert not torch.allclose(prior, readout)  # the head corrects every channel: the test could fail
    scales = {"roughness": 0.5, "albedo": 0.25}
    scaled = clean_estimate(scale_readout_correction(ckpt, scales), inputs, f_t)
    for channel, columns in CHANNELS.items():
        keep = scales.get(channel, 1.0)
        expected = readout[..., columns] + keep * (prior[..., columns] - readout[..., columns])
        assert torch.allclose(scaled[..., columns], expected, atol=1e-5), channel
    assert scale_readout_correction(ckpt, {"roughness": 0.0})["ema"]["out.bias"][3] == 0


def test_the_scales_are_recorded_multiplied_and_the_source_is_not_changed():
    ckpt = trained_checkpoint()
    bias = ckpt["ema"]["out.bias"].clone()
    once = scale_readout_correction(ckpt, {"roughness": 0.5})
    twice = scale_readout_correction(once, {"roughness": 0.5, "metallic": 1.0})
    assert once["config"]["readout_correction_scale"] == {"roughness": 0.5}
    assert twice["config"]["readout_correction_scale"] == {"roughness": 0.25, "metallic": 1.0}
    assert torch.equal(ckpt["ema"]["out.bias"], bias) and "model" not in once
    assert torch.allclose(twice["ema"]["out.bias"][3], bias[3] * 0.25)


def test_a_model_without_the_readout_head_an_unknown_channel_or_a_scale_outside_0_1_is_refused():
    with pytest.raises(CheckpointError, match="m.pt: a correction scale applies to an x0_readout head"):
        scale_readout_correction(trained_checkpoint("x0"), {"roughness": 0.5}, "m.pt")
    with pytest.raises(ValueError, match="unknown channel 'gloss'"):
        scale_readout_correction(trained_checkpoint(), {"gloss": 0.5})
    with pytest.raises(ValueError, match="1.5 is not a fraction between 0 and 1"):
        scale_readout_correction(trained_checkpoint(), {"roughness": 1.5})
