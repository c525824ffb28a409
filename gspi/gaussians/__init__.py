"""2D Gaussian surfels (2DGS): container, PLY I/O, cameras and rasterization."""

from gspi.gaussians.model import Gaussians2D
from gspi.gaussians.ply import PlyFormatError, read_ply, write_ply
from gspi.gaussians.rasterize import RenderOutput, rasterize_2dgs, render_gaussians

__all__ = [
    "Gaussians2D",
    "PlyFormatError",
    "RenderOutput",
    "rasterize_2dgs",
    "read_ply",
    "render_gaussians",
    "write_ply",
]
