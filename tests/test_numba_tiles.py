"""The numba binning equals the torch reference's tile lists (gspi/gaussians/numba_tiles.py)."""
import pytest
import torch

from gspi.gaussians.numba_tiles import bin_splats_numba
from gspi.gaussians.tiles import bin_splats


def boxes(n: int, width: int, height: int, seed: int, *, max_extent: int = 20, tied_depths: bool = False):
    """Random inclusive pixel boxes inside the image, a random valid mask and depths."""
    g = torch.Generator().manual_seed(seed)
    size = torch.tensor([width, height])
    lo = (torch.rand(n, 2, generator=g) * size).long()
    hi = torch.minimum(lo + (torch.rand(n, 2, generator=g) * max_extent).long(), size - 1)
    valid = torch.rand(n, generator=g) > 0.2
    depths = torch.rand(n, generator=g) * 4 + 0.1
    if tied_depths:  # many equal depths: ties go by surfel index in both
        depths = (depths * 3).round() / 3
    return lo, hi, valid, depths


def assert_same_bins(*args):
    ref, got = bin_splats(*args), bin_splats_numba(*args)
    assert (got.tile_size, got.tiles_x, got.tiles_y) == (ref.tile_size, ref.tiles_x, ref.tiles_y)
    assert torch.equal(got.offsets, ref.offsets)
    assert torch.equal(got.splat_ids, ref.splat_ids)
    return got


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("tile_size", [8, 16])
def test_same_lists_as_the_reference(seed, tile_size):
    lo, hi, valid, depths = boxes(600, 100, 72, seed)
    bins = assert_same_bins(lo, hi, valid, depths, 100, 72, tile_size)
    assert len(bins.splat_ids) > 600  # boxes span several tiles


def test_tied_depths_keep_the_index_order():
    lo, hi, valid, depths = boxes(500, 64, 64, 3, tied_depths=True)
    assert len(depths.unique()) < 20
    assert_same_bins(lo, hi, valid, depths, 64, 64, 8)


def test_float64_depths_whole_image_boxes_and_edge_tiles():
    lo, hi, valid, depths = boxes(200, 37, 23, 4, max_extent=60)  # partial tiles at the edges
    lo[:5], hi[:5] = 0, torch.tensor([36, 22])  # whole-image boxes (unbounded projections)
    assert_same_bins(lo, hi, valid, depths.double(), 37, 23, 8)


def test_nothing_valid_gives_empty_lists():
    lo, hi, _, depths = boxes(50, 32, 32, 5)
    bins = assert_same_bins(lo, hi, torch.zeros(50, dtype=torch.bool), depths, 32, 32, 8)
    assert len(bins.splat_ids) == 0 and bins.offsets.tolist() == [0] * 17
    assert_same_bins(lo[:0], hi[:0], torch.zeros(0, dtype=torch.bool), depths[:0], 32, 32, 8)
