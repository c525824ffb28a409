"""Dataset sources of GS-PI, in three floors (lower never imports upper; tests/test_imports.py):
the shared facts, the rooms that use them, and the dataset writer on top. Rooms:

    procedural/     the procedural PBR benchmark generator (shapes, materials, recipes, rendering)
    assets/         glTF/GLB objects (reader, mesh rendering, import) and path tracing
    layouts/        the field's dataset layouts (NeRF-synthetic, TensoIR, Stanford-ORB, NeRO)
    pool/           Stage II's training pool (recipes, splits, reconstructed conditions)

and the facts they share:

    lattice         the canonical V = 32 Fibonacci hemisphere lattice and its cameras
    environments    procedural HDR lat-long environments (capture and held-out sets)
    hdri            real HDRIs as environments
    env_sets        a scene's capture / held-out environment sets
    point_clouds    GT point clouds of the lattice views (gt_points.npz)
    gt_maps         the GT material maps of a view
    contact_sheet   per-scene preview PNG
    pmndrs_assets   the HDRIs and test glTF models fetched from the npm registry at install time

and above them all:

    generate        the whole dataset (splits.json, workers, determinism)
Entry point: `gspi-data` (gspi/cli/data.py).
"""
