"""LPIPS v0.1 without the `lpips` package: ``net`` (AlexNet / VGG16 trunks and the linear
heads, eval's perceptual metric) and ``weights`` (the converted weights, fetched at install
time with checksums and checked against the original package's)."""
