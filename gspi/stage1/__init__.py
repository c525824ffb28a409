"""Stage I (paper, "Point Cloud Extraction"): 2DGS asset -> filtered, source-anchored point cloud."""
