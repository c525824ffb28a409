"""MaterialAnything (3DTopia/MaterialAnything @ be3d6b3) adapter: mesh in, UV textures out.

MaterialAnything is a generative, mesh-based method: it reads a UV-mapped `mesh.obj`, an initial
UV albedo `texture_kd.png` and a text prompt, renders its own viewpoints and writes UV material
textures. It never sees the benchmark's images or cameras, and this harness extracts no mesh:
the user supplies a UV-mapped OBJ in the scene's world coordinates (option `mesh`, e.g. a
mesh of the scene's 2DGS asset unwrapped with xatlas; `{scene}` in the path is replaced by the
scene name).

Export (`<out>/`): `mesh.obj` (the user's mesh, rotated Z-up -> Y-up with `y_up: true`, the
axes its `--use_objaverse` viewpoints assume; `mtllib`/`usemtl` lines dropped), `mesh_world.obj`
(the user's mesh as given), `texture_kd.png` (option `texture_kd`, else a uniform mid-grey
1024^2 image: the script opens it unconditionally), `prompt.txt` (option `prompt`).
Commands: `scripts/generate_texture_pbr_3d.py --input_dir <out> --output_dir <model> ...`, then
`cp <out>/mesh_world.obj <model>/input_mesh.obj` so the model dir is self-contained.

Import: the UV textures `<model>/generate/material/final_albedo_after.png` (sRGB-encoded) and
`final_rm_after.png` (linear; G = roughness, B = metallic) are rendered on the input mesh (the
output mesh keeps its UV layout) at the scene's cameras of the scored split (test, or the
lattice views) with baselines.mesh_render. The
mesh is `mesh` if set, else `<model>/input_mesh.obj`. Pixels the mesh does not cover are 0.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.adapter import Adapter, AdapterError, read_output_png
from baselines.mesh_render import MeshError, UVMesh, read_obj, render_uv_maps
from eval.common.imageio import write_png
from eval.common.layout import Scene, View, read_scene

Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x,y,z)->(x,z,-y)
MATERIAL_DIR = Path("generate") / "material"
ALBEDO_TEXTURE, RM_TEXTURE = "final_albedo_after.png", "final_rm_after.png"
INPUT_MESH = "input_mesh.obj"  # copy of the world-space mesh in the model dir
INIT_TEXTURE_SIZE = 1024


def mesh_path(cfg: dict, scene_name: str) -> Path | None:
    """The user's mesh of this scene, or None when the `mesh` option is unset.

    `mesh` is an OBJ file, a folder holding `<scene name>.obj`, or a path with `{scene}`.
    """
    template = cfg.get("mesh")
    if template is None:
        return None
    path = Path(str(template).replace("{scene}", scene_name))
    return path / f"{scene_name}.obj" if path.is_dir() else path


def rotate_obj_text(text: str, rotation: np.ndarray) -> str:
    """Rotate the `v` records of an OBJ text by `rotation` [3, 3]; drop mtllib/usemtl lines."""
    out = []
    for line in text.splitlines():
        parts = line.split()
        if parts and parts[0] == "v":
            xyz = rotation @ np.asarray([float(x) for x in parts[1:4]])
            out.append("v " + " ".join(f"{c:.9g}" for c in xyz) + "".join(
                " " + x for x in parts[4:]))
        elif not parts or parts[0] not in ("mtllib", "usemtl"):
            out.append(line)
    return "\n".join(out) + "\n"


def load_mesh(path: Path) -> UVMesh:
    try:
        return read_obj(path)
    except MeshError as exc:
        raise AdapterError(str(exc)) from exc


class MaterialAnythingAdapter(Adapter):
    name = "materialanything"
    rendered_splits = ("train", "val", "test")  # its textures are rendered here, at any camera

    def export(self, scene_dir, out_dir, cfg) -> Path:
        scene, out = read_scene(scene_dir), Path(out_dir)
        path = mesh_path(cfg, scene.name)
        if path is None:
            raise AdapterError("materialanything needs a UV-mapped mesh of the scene in world "
                               "coordinates: set method.mesh=<OBJ file, or folder of "
                               "<scene name>.obj> (this harness extracts no mesh)")
        load_mesh(path)  # validates: exists, has faces with texture coordinates
        text = path.read_text()
        rotation = Z_UP_TO_Y_UP if cfg.get("y_up", True) else np.eye(3)
        out.mkdir(parents=True, exist_ok=True)
        (out / "mesh.obj").write_text(rotate_obj_text(text, rotation))
        (out / "mesh_world.obj").write_text(text)
        texture = cfg.get("texture_kd")
        if texture is not None:
            texture = Path(str(texture).replace("{scene}", scene.name))
            write_png(out / "texture_kd.png", read_output_png(texture, "initial UV albedo")[..., :3])
        else:
            write_png(out / "texture_kd.png", np.full((INIT_TEXTURE_SIZE, INIT_TEXTURE_SIZE, 3), 0.5))
        (out / "prompt.txt").write_text(str(cfg.get("prompt", "an object")) + "\n")
        return out

    def template_fields(self, cfg: dict) -> dict[str, str]:
        return {"prompt": str(cfg.get("prompt", "an object")), "input_mesh": INPUT_MESH}

    def open_outputs(self, src: Path, scene: Scene, cfg: dict, split: str) -> tuple[UVMesh, dict]:
        """The world-space mesh and the textures {"albedo": sRGB, "rm": linear (G, B used)}."""
        material = src / MATERIAL_DIR
        textures = {"albedo": read_output_png(material / ALBEDO_TEXTURE,
                                              "refined UV albedo, sRGB")[..., :3],
                    "rm": read_output_png(material / RM_TEXTURE,
                                          "refined UV roughness (G) / metallic (B)")}
        if textures["rm"].shape[-1] != 3:
            raise AdapterError(f"{material / RM_TEXTURE}: expected RGB (G = roughness, "
                               f"B = metallic), found {textures['rm'].shape[-1]} channel(s)")
        path = mesh_path(cfg, scene.name) or src / INPUT_MESH
        return load_mesh(path), textures

    def read_view(self, outputs: tuple[UVMesh, dict], index: int, view: View, scene: Scene,
                  cfg: dict) -> dict[str, np.ndarray]:
        mesh, textures = outputs
        _, maps = render_uv_maps(mesh, textures, view.K, view.w2c, scene.height, scene.width)
        return {"albedo": maps["albedo"], "roughness": maps["rm"][..., 1],
                "metallic": maps["rm"][..., 2]}
