"""Make the small coloured test meshes beside this file (run from anywhere):
a closed box painted by height, red above its middle and blue below, three
ways: vertex colours (box_vertex.ply), a texture in a GLB (box_texture.glb)
and an OBJ with its MTL and PNG whose UVs lie in [1, 2] (box_texture.obj,
box_texture.mtl, box_texture.png: read by repeating, so red above and blue below
as well). Deterministic: the same bytes each run."""

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

HERE = Path(__file__).parent
TOP, BOTTOM = (220, 40, 30), (30, 60, 200)  # sRGB


def box() -> trimesh.Trimesh:
    """A 2 x 1 x 1.5 box (z up) cut into small triangles, so colours vary within it."""
    mesh = trimesh.creation.box(extents=(2.0, 1.0, 1.5))
    for _ in range(3):
        mesh = mesh.subdivide()
    return mesh


def main() -> None:
    mesh = box()
    above = mesh.vertices[:, 2] > 0
    colours = np.where(above[:, None], TOP, BOTTOM)
    rgba = np.concatenate([colours, np.full((len(colours), 1), 255)], axis=1).astype(np.uint8)
    painted = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=rgba, process=False)
    (HERE / "box_vertex.ply").write_bytes(painted.export(file_type="ply"))

    # A texture 4 pixels wide and 8 high: top rows red, bottom rows blue; v follows height.
    image = Image.fromarray(np.array([TOP] * 4 + [BOTTOM] * 4, np.uint8)[:, None].repeat(4, axis=1))
    z = mesh.vertices[:, 2]
    uv = np.stack([0.5 + 0.2 * mesh.vertices[:, 0], (z - z.min()) / np.ptp(z) * 0.9 + 0.05], axis=1)
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image)
    textured = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=uv, material=material))
    (HERE / "box_texture.glb").write_bytes(textured.export(file_type="glb"))

    image.save(HERE / "box_texture.png")
    lines = ["mtllib box_texture.mtl", "usemtl painted"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
    lines += [f"vt {u:.6f} {v + 1:.6f}" for u, v in uv]  # in [1, 2]: wraps to the same place
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in mesh.faces + 1]
    (HERE / "box_texture.obj").write_text("\n".join(lines) + "\n")
    (HERE / "box_texture.mtl").write_text("newmtl painted\nKd 1 1 1\nmap_Kd box_texture.png\n")


if __name__ == "__main__":
    main()
