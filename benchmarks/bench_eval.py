"""Speed of the evaluation protocol's pieces at 128 and 512 px (medians, machine named).

    python -m benchmarks.bench_eval
"""
from __future__ import annotations

import torch

from benchmarks.common import machine, median_seconds
from eval.lpips.net import load_lpips
from eval.metrics import masked_lpips, masked_psnr, masked_ssim
from eval.relight import clear_prefilter_cache, prefilter_environment, split_sum


def main() -> None:
    print(f"machine: {machine()}")
    g = torch.Generator().manual_seed(0)
    net = load_lpips()
    for size in (128, 512):
        pred, gt = torch.rand(size, size, 3, generator=g), torch.rand(size, size, 3, generator=g)
        mask = torch.zeros(size, size, dtype=torch.bool)
        mask[size // 8:-size // 8, size // 8:-size // 8] = True
        for name, fn in (("psnr", lambda: masked_psnr(pred, gt, mask)),
                         ("ssim", lambda: masked_ssim(pred, gt, mask)),
                         ("lpips", lambda: masked_lpips(pred, gt, mask, net=net))):
            print(f"{size:4d} px  {name:<6} {1000 * median_seconds(fn):8.1f} ms (median of 5)")
        n = torch.nn.functional.normalize(torch.randn(size, size, 3, generator=g), dim=-1)
        env = torch.rand(size // 2, size, 3, generator=g) * 4
        pre = prefilter_environment(env)
        args = (pred, pred[..., :1], pred[..., 1:2], n, n)
        t = median_seconds(lambda: split_sum(*args, pre))
        print(f"{size:4d} px  split_sum {1000 * t:8.1f} ms for {size}x{size} pixels")

    for h in (128, 256):
        env = torch.rand(h, 2 * h, 3, generator=g) * 4

        def prefilter():
            clear_prefilter_cache()
            prefilter_environment(env)
        print(f"prefilter {h}x{2 * h} env: {median_seconds(prefilter, repeats=3):.2f} s (median of 3)")


if __name__ == "__main__":
    main()
