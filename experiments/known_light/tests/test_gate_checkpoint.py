import pytest
import torch

from experiments.known_light.gate_checkpoint import with_metal_gate
from gspi.stage2.checkpoint import CHECKPOINT_FORMAT, CHECKPOINT_VERSION, CheckpointError, rcw_config_dict
from gspi.stage2.config import complete_stage2
from gspi.stage2.model import RCWConfig, RCWDenoiser


def tiny_checkpoint(prediction: str) -> dict:
    rcw = RCWConfig(num_latents=4, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1, num_heads=2,
                    local_cond_dim=42, global_token_dim=0, prediction=prediction,
                    readout_column=35 if prediction == "x0_readout" else None)
    state = RCWDenoiser(rcw).state_dict()
    stage2 = complete_stage2({"diffusion": {"prediction": prediction},
                              "data": {"light_readout": prediction == "x0_readout"}})
    from dataclasses import asdict
    return {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "step": 7, "rcw_config": rcw_config_dict(rcw),
            "config": {"stage2": asdict(stage2), "seed": 0}, "ema": state, "model": state}


def test_the_gate_is_switched_on_and_the_weights_kept():
    ckpt = tiny_checkpoint("x0_readout")
    out = with_metal_gate(ckpt)
    assert out["rcw_config"]["readout_metal_gate"] and out["config"]["stage2"]["diffusion"]["readout_metal_gate"]
    assert not ckpt["rcw_config"]["readout_metal_gate"]  # the source is not changed
    assert "model" not in out and all(torch.equal(out["ema"][k], v) for k, v in ckpt["ema"].items())
    assert complete_stage2(out["config"]["stage2"]).diffusion.readout_metal_gate
    RCWDenoiser(RCWConfig(**out["rcw_config"])).load_state_dict(out["ema"])


def test_a_model_without_the_readout_head_is_refused():
    with pytest.raises(CheckpointError, match="corrects an x0_readout head"):
        with_metal_gate(tiny_checkpoint("x0"), "m.pt")
