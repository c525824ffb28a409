"""Stage II's training pool: its recipes, its train/val/test splits, and the conditions read from
a 2DGS asset instead of the GT renders (the reconstructed pool, as the paper trains; the Stage 0
job that writes it is gspi.recon.reconstructed_pool, one floor up).

    training_pool     the pool's scene recipes (`gspi-data preset=stage2_pool`), done markers
    split             `python -m gspi.data.pool.split POOL OUT --train a:b --test c:d`
    asset_conditions  a scene folder whose Stage II conditions are an asset's lattice renders
"""
