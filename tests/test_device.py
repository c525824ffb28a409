"""device=auto|cpu|cuda (gspi/device.py) and the Stage II Write-chunk halving on CUDA OOM."""
from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from gspi.device import DeviceError, resolve_device
from gspi.stage2.oom import run_with_chunk_halving

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="checks the no-CUDA error")


def test_auto_and_cpu_resolve_without_cuda():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == torch.device("cuda" if torch.cuda.is_available() else "cpu")


@no_cuda
@pytest.mark.parametrize("value", ["cuda", "cuda:0"])
def test_cuda_without_cuda_is_one_clear_error(value):
    with pytest.raises(DeviceError, match=r"device=cuda.*not available.*device=cpu or device=auto"):
        resolve_device(value)


@pytest.mark.parametrize("value", ["GPU0", "cdua", "cpu:1", "cuda:x"])
def test_typo_lists_the_choices(value):
    with pytest.raises(DeviceError, match=r"expected one of auto, cpu, cuda"):
        resolve_device(value, key="device")


@no_cuda
def test_run_config_check_fails_at_start_up():
    from gspi.run.config_check import check_run_config

    with pytest.raises(DeviceError, match="device=cuda"):
        check_run_config({"split": "test", "data_dir": "d", "out": "o", "device": "cuda"})


def _fake_oom_above(limit: int, calls: list):
    def fn(chunk):
        calls.append(chunk)
        if chunk is None or chunk > limit:
            raise torch.cuda.OutOfMemoryError("CUDA out of memory (injected)")
        return f"ran at {chunk}"
    return fn


def test_chunk_halves_until_it_fits_and_logs(caplog):
    calls = []
    with caplog.at_level(logging.WARNING, logger="gspi.stage2.oom"):
        result, chunk = run_with_chunk_halving(_fake_oom_above(5000, calls), 32768, num_points=100_000)
    assert calls == [32768, 16384, 8192, 4096] and chunk == 4096 and result == "ran at 4096"
    assert sum("retrying with" in r.message for r in caplog.records) == 3


def test_no_chunking_starts_from_half_the_cloud_and_gives_up_at_the_floor():
    calls = []
    _, chunk = run_with_chunk_halving(_fake_oom_above(3000, calls), None, num_points=10_000)
    assert calls == [None, 5000, 2500] and chunk == 2500
    with pytest.raises(torch.cuda.OutOfMemoryError):
        run_with_chunk_halving(_fake_oom_above(10, []), 4096, num_points=10_000, min_chunk=1024)


def test_other_errors_are_not_retried():
    def boom(chunk):
        raise RuntimeError("not memory")
    with pytest.raises(RuntimeError, match="not memory"):
        run_with_chunk_halving(boom, 1024, num_points=4096)


def _tiny_model():
    from gspi.stage2.model import RCWConfig, RCWDenoiser

    torch.manual_seed(0)
    return RCWDenoiser(RCWConfig(num_latents=4, latent_dim=16, point_dim=16, num_blocks=1, num_compute_layers=1,
                                 num_heads=2, mlp_ratio=2.0, fourier_bands=2, local_cond_dim=3,
                                 use_view_onehot=False, global_token_dim=0)).eval()


def test_sampling_on_the_cpu_device_is_the_old_path_and_chunk_free():
    from gspi.stage2.sampler import predict_point_pbr

    rng = np.random.default_rng(0)
    xyz, cond = rng.normal(size=(300, 3)), rng.uniform(size=(300, 3)).astype(np.float32)
    model = _tiny_model()
    old = predict_point_pbr(model, xyz, cond, None, num_steps=3, write_chunk=None)
    cpu = predict_point_pbr(model, xyz, cond, None, num_steps=3, write_chunk=None, device=torch.device("cpu"))
    small = predict_point_pbr(model, xyz, cond, None, num_steps=3, write_chunk=64)
    assert torch.equal(old, cpu)  # device=cpu: the same numbers as before
    assert torch.allclose(old, small, atol=1e-6)  # a halved chunk does not change the result


def test_gspi_and_eval_share_one_resolver():
    """gspi-eval (eval/, which never imports gspi) and the gspi commands accept the same values
    and fail alike: gspi.device is eval.common.device under its gspi name, not a copy that could drift."""
    import eval.common.device
    import gspi.device

    assert gspi.device.resolve_device is eval.common.device.resolve_device
    assert gspi.device.DeviceError is eval.common.device.DeviceError and issubclass(DeviceError, ValueError)
    assert eval.common.device.resolve_device("auto") == resolve_device("auto")
    assert eval.common.device.resolve_device(" CPU ") == torch.device("cpu")


def _eval_cfg(tmp_path, device):
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose("gspi_eval", overrides=[f"gt={tmp_path}", f"pred={tmp_path}", f"out={tmp_path / 'ev'}",
                                               f"device={device}", "progress=false"])


@no_cuda
def test_eval_device_cuda_fails_at_start_up_before_writing(tmp_path):
    from eval.cli import run

    (tmp_path / "ev").mkdir()
    (tmp_path / "ev" / "summary.json").write_text("{}")
    with pytest.raises(DeviceError, match=r"device=cuda.*not available"):
        run(_eval_cfg(tmp_path, "cuda"))
    assert (tmp_path / "ev" / "summary.json").is_file()  # refused before clearing the old result


class _Stop(Exception):
    pass


def _capture_device(seen: dict):
    def fake_evaluate(*args, device=None, **kwargs):
        seen["device"] = device
        raise _Stop
    return fake_evaluate


def test_gspi_eval_passes_the_resolved_device(tmp_path, monkeypatch):
    import eval.cli

    seen = {}
    monkeypatch.setattr(eval.cli, "evaluate", _capture_device(seen))
    with pytest.raises(_Stop):
        eval.cli.run(_eval_cfg(tmp_path, "auto"))
    assert seen["device"] == resolve_device("auto")


def test_gspi_run_scores_on_the_runs_device(tmp_path, monkeypatch):
    from omegaconf import OmegaConf

    import eval.evaluate
    from eval.config import ProtocolConfig
    from gspi.run.runner import evaluate_predictions

    seen = {}
    monkeypatch.setattr(eval.evaluate, "evaluate", _capture_device(seen))
    protocol = OmegaConf.to_container(OmegaConf.structured(ProtocolConfig))
    with pytest.raises(_Stop):
        evaluate_predictions({"eval": protocol, "device": "auto"}, tmp_path, tmp_path, "m")
    assert seen["device"] == resolve_device("auto")


@no_cuda
@pytest.mark.parametrize("mode", [[], ["import.src=nerf/lego"]])
def test_data_device_cuda_fails_at_start_up_before_writing(tmp_path, mode):
    """gspi-data, whatever the mode: refused before the output folder is made."""
    from hydra import compose, initialize_config_dir

    from eval.common.conf import CONF_DIR
    from eval.common.argv import apply_aliases
    from gspi.cli.data import run

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose("gspi_data", overrides=apply_aliases(["preset=tiny", f"out={tmp_path / 'd'}",
                                                           "device=cuda", *mode], "gspi_data"))
    with pytest.raises(DeviceError, match=r"device=cuda.*not available"):
        run(cfg)
    assert not (tmp_path / "d").exists()
