"""Game assets: fidelity, speed and size, side by side in one run (docs/ASSETS.md).

    python benchmarks/asset.py fidelity [--model towerruins] [--seed 3] [--scale 4] [--lods 20000,5000,1200]
                                        [--texture 2048] [--gltfpack PATH] [--pictures DIR]
    python benchmarks/asset.py speed [--model towerruins] [--scale 4] [--lods 5000] [--texture 2048 | 0] [--compress]
                                     [--repeats 3]
    python benchmarks/asset.py cycles [--model towerruins] [--scale 2] [--lods 1200] [--texture 1024] --pictures DIR
    python benchmarks/asset.py hulls [--models towerruins acropolis terrain brickruin] [--scale 1]
    python benchmarks/asset.py base [--models towerruins acropolis terrain brickruin] [--scale 1] [--lods 5000]
    python benchmarks/asset.py size [--models towerruins acropolis terrain brickruin] [--scale 1] [--lods 20000,5000,1200]
                                    [--texture 1024]
    python benchmarks/asset.py engines [--models ...] [--scale 1] [--seeds 10] [--lods 20000,5000,1200]

fidelity: the sample's asset, each level drawn with its normal map, beside
the full-resolution mesh drawn with its own smooth normals, from 6 views
(four around, one high, one low), orthographic, lit as `sinrun render`
lights (two lights fixed to the camera): silhouette IoU and the mean
brightness difference where both are drawn (in % of full brightness).
Beside them, at the same triangle counts: the level without its normal map,
Blender's Decimate modifier (collapse) and gltfpack (meshoptimizer's command
line, -si, floats kept), both with their own smooth normals (they bake no
maps). --pictures writes one view of each, side by side. Needs bpy
(pip install 'sinshape[blender]') and gltfpack (npm install --prefix
tools/node gltfpack; --gltfpack names its binary), each table row skipped
where one is missing.

speed: the sample alone (`sinrun sample -o x.ply`, made in memory) against
its asset (--lods, --texture), alternated, the best of --repeats, after one
untimed sample (a process's first sample pays for its imports: trimesh and
scipy take about 1 s, eight times a tower's sample at scale 1); then
Blender baking the same maps from the same meshes (Cycles, selected to
active, one sample: the normal map, and the colour for a coloured model),
and the sizes: the .glb against the dense mesh's .glb and .ply.

cycles: the full mesh (`sinrun sample -o x.glb`) and the asset's coarsest
level with its maps, each imported by Blender's glTF importer and rendered
by Cycles side by side: an engine's own reading of the normal map (Blender
builds its own tangents).

size: each model's asset with its maps sized to the sample (floats,
quantised, compressed) and at --texture, against the full mesh's .glb
(the plain sample), whole files and their geometry (all but the maps).

hulls: the convex collision (asset.convex_hulls) of each model's sample at
8, 16 and 32 hulls, and at 16 with CoACD's own defaults (threshold 0.05) and with V-HACD (where vhacdx is
installed): seconds, hulls,
and, from 200,000 random points in the sample's bounds judged by the
model's own field, the share of the solid inside some hull (covered) and
the hulls' volume outside the solid, as a share of the solid's (excess).

engines: each model's asset at the defaults, seeds 0 to --seeds - 1, in
the validator, Godot 3 and Babylon.js (tools/importers.py, as the tests
drive them): errors and warnings, what each draws, the collision Godot makes.

base: the share of a level's atlas the faces of its base take (those on
the ground: asset.on_the_ground), charted with the others and charted
apart as unseen (asset.unwrap), and how many more texels per unit of
surface the other faces get for it.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")  # as `sinrun` runs (cli/__init__.py), set before numpy loads
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
VIEWS = [(35, 25), (125, 25), (215, 25), (305, 25), (80, 70), (170, -15)]
PICTURE_SIZE = 512


def load(name: str, threads: int = 2):
    from sinshape import models
    from sinshape.runtime import load_model

    return load_model(models.find(name), threads=threads)


def make_asset(model, seed: int, scale: float, lods: tuple, texture: int) -> tuple:
    """(the sample's mesh (vertices, faces) in the input frame, as `sinrun
    sample` makes it (with its example's relief at scale 2 and up), its
    vertex colours (uint8, None for a geometry-only model), the .glb, info)."""
    from sinshape.runtime import asset, colour
    from sinshape.runtime.request import SampleRequest

    request = SampleRequest(seed, scale=scale)
    dense = asset.dense_surface(model, request)
    vertices = dense.frame.to_model(dense.vertices)
    if dense.field.relief is not None and scale >= colour.RELIEF_SCALE:
        vertices = dense.field.relief(vertices)
    data, info = asset.asset_bytes(model, request, asset.AssetOptions(lods, texture), model.path.stem)
    colours = dense.field.colour(vertices) if dense.field.colour else None
    return (dense.frame.from_model(vertices), dense.faces), colours, data, info


# --- drawing -------------------------------------------------------------------------------------------

def vertex_normals(vertices, faces):
    from sinshape.runtime import bake

    return bake.vertex_normals(np.asarray(vertices, np.float64), np.asarray(faces))


def welded(vertices, faces) -> tuple:
    unique, index = np.unique(np.asarray(vertices), axis=0, return_inverse=True)
    return unique, index.reshape(-1)[np.asarray(faces)]


class Camera:
    """An orthographic view framing a box (the dense mesh's), lit as sinrun render lights."""

    def __init__(self, box: np.ndarray, view: tuple, up: str, size: int = PICTURE_SIZE):
        from sinshape.runtime import render

        self.axes = render.camera_axes(*view, up)
        self.centre = box.mean(axis=0)
        corners = np.array(np.meshgrid(*box.T)).reshape(3, -1).T
        self.radius = np.abs((corners - self.centre) @ self.axes[:2].T).max() / 0.9
        self.size = size

    def draw(self, vertices, faces, shading, albedo=None) -> tuple:
        """(mask (H, W) bool, brightness (H, W) float, colour (H, W, 3) in [0, 1]):
        shading(face, weights) gives each drawn pixel's world normal from its
        face and barycentric weights, albedo(face, weights) its sRGB colour
        (None: grey)."""
        from sinshape.runtime import raster, render

        camera = (np.asarray(vertices, np.float64) - self.centre) @ self.axes.T
        pixels = (camera[:, :2] / self.radius * [0.5, -0.5] + 0.5) * self.size
        corners = pixels[faces]
        owner, _ = raster.rasterise(corners, camera[faces][..., 2], (self.size, self.size))
        drawn = np.flatnonzero(owner.ravel() >= 0)
        face = owner.ravel()[drawn]
        centre = np.stack([drawn % self.size, drawn // self.size], axis=1) + 0.5
        a, e1, e2 = corners[face, 0], corners[face, 1] - corners[face, 0], corners[face, 2] - corners[face, 0]
        q = centre - a
        area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        w1 = (q[:, 0] * e2[:, 1] - q[:, 1] * e2[:, 0]) / area
        w2 = (e1[:, 0] * q[:, 1] - e1[:, 1] * q[:, 0]) / area
        weights = np.stack([1 - w1 - w2, w1, w2], axis=1)
        normals = shading(face, weights) @ self.axes.T  # camera frame: z towards the eye
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        light = np.full(len(drawn), render.AMBIENT)
        for direction, strength in render.LIGHTS:
            light += strength * np.maximum(normals @ (np.array(direction) / np.linalg.norm(direction)), 0)
        mask, brightness = np.zeros(self.size * self.size, bool), np.zeros(self.size * self.size)
        mask[drawn], brightness[drawn] = True, light
        colour = np.full((self.size * self.size, 3), 0.98)
        colour[drawn] = light[:, None] * (albedo(face, weights) if albedo else 0.85)
        return (mask.reshape(self.size, self.size), brightness.reshape(self.size, self.size),
                np.clip(colour, 0, 1).reshape(self.size, self.size, 3))


def smooth_shading(vertices, faces):
    normals = vertex_normals(vertices, faces)
    return lambda face, weights: np.einsum("pk,pkc->pc", weights, normals[faces[face]])


def vertex_albedo(faces, colours):
    """Per-pixel colour interpolated from (V, 3) uint8 vertex colours."""
    return lambda face, weights: np.einsum("pk,pkc->pc", weights, colours[faces[face]] / 255.0)


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """A (S, S, C) map at UVs (k, 2), texel centres at (i + 0.5) / S."""
    size = image.shape[0]
    uv = uv * size - 0.5
    low = np.clip(np.floor(uv).astype(int), 0, size - 2)
    f = np.clip(uv - low, 0, 1)
    x0, y0 = low[:, 0], low[:, 1]
    return (image[y0, x0] * ((1 - f[:, :1]) * (1 - f[:, 1:])) + image[y0, x0 + 1] * (f[:, :1] * (1 - f[:, 1:]))
            + image[y0 + 1, x0] * ((1 - f[:, :1]) * f[:, 1:]) + image[y0 + 1, x0 + 1] * (f[:, :1] * f[:, 1:]))


def mapped_albedo(arrays: dict):
    """A level's colour from its base-colour map."""
    colours = arrays["colour_map"].astype(np.float64) / 255
    return lambda face, weights: bilinear(colours, np.einsum("pk,pkc->pc", weights,
                                                             arrays["texcoord_0"][arrays["faces"][face]]))


def mapped_shading(arrays: dict):
    """A level's normal from its normal map (bilinear), through its tangent frame."""
    faces = arrays["faces"]
    texels = arrays["normal_map"].astype(np.float64) / 255 * 2 - 1

    def shading(face, weights):
        corners = faces[face]
        n = np.einsum("pk,pkc->pc", weights, arrays["normal"][corners].astype(np.float64))
        t = np.einsum("pk,pkc->pc", weights, arrays["tangent"][corners, :3].astype(np.float64))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        b = np.cross(n, t) * arrays["tangent"][corners[:, 0], 3:]
        b /= np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
        c = bilinear(texels, np.einsum("pk,pkc->pc", weights, arrays["texcoord_0"][corners].astype(np.float64)))
        return t * c[:, :1] + b * c[:, 1:2] + n * c[:, 2:]
    return shading


def compare(reference: tuple, drawn: tuple) -> tuple:
    """(silhouette IoU, mean brightness difference in % where both are drawn)."""
    (mask_a, light_a, _), (mask_b, light_b, _) = reference, drawn
    both = mask_a & mask_b
    return both.sum() / (mask_a | mask_b).sum(), 100 * np.abs(light_a - light_b)[both].mean()


# --- the others: Blender's Decimate, gltfpack -----------------------------------------------------------

BLENDER_DECIMATE = """
import sys, time, json
import numpy as np
sys.path.insert(0, {root!r})
import bpy
from blender import convert
bpy.ops.wm.read_factory_settings(use_empty=True)
data = np.load({dense!r})
results = {{}}
for target in {targets!r}:
    mesh = bpy.data.meshes.new("dense")
    convert.fill_mesh(mesh, data["vertices"], data["faces"])
    obj = bpy.data.objects.new("dense", mesh)
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.view_layer.objects.active = obj
    started = time.perf_counter()
    modifier = obj.modifiers.new("decimate", "DECIMATE")
    modifier.ratio = target / len(data["faces"])
    modifier.use_collapse_triangulate = True
    bpy.ops.object.modifier_apply(modifier="decimate")
    seconds = time.perf_counter() - started
    vertices, faces = convert.mesh_arrays(obj.data)
    np.savez({out!r}.replace("TARGET", str(target)), vertices=vertices, faces=faces)
    results[target] = seconds
    bpy.data.objects.remove(obj)
print("RESULT" + json.dumps(results))
"""


def blender(script: str) -> dict | None:
    """Run a script in Blender (bpy, in a process of its own): its RESULT line, or None without bpy."""
    try:
        import importlib.util

        if importlib.util.find_spec("bpy") is None:
            return None
    except ValueError:
        return None
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT")]
    if not lines:
        raise RuntimeError(f"Blender failed: {done.stderr[-2000:]}")
    return json.loads(lines[-1][6:])


def decimated(dense: tuple, targets: tuple, folder: Path) -> dict:
    """{target: (vertices, faces, seconds)} from Blender's Decimate modifier (collapse)."""
    path = folder / "dense.npz"
    np.savez(path, vertices=dense[0], faces=dense[1])
    out = str(folder / "decimated_TARGET.npz")
    times = blender(BLENDER_DECIMATE.format(root=str(ROOT), dense=str(path), targets=list(targets), out=out))
    if times is None:
        return {}
    result = {}
    for target in targets:
        arrays = np.load(out.replace("TARGET", str(target)))
        faces = np.asarray(arrays["faces"])
        result[target] = (arrays["vertices"], faces, times[str(target)])
    return result


def gltfpacked(dense: tuple, targets: tuple, folder: Path, binary: str | None) -> dict:
    """{target: (vertices, faces, seconds)} from gltfpack -si (simplify to a ratio), floats kept (-noq)."""
    import trimesh

    binary = binary or shutil.which("gltfpack") or str(ROOT / "tools" / "node" / "node_modules" / ".bin" / "gltfpack")
    if not Path(binary).exists():
        return {}
    source = folder / "dense.glb"
    trimesh.Trimesh(*dense, process=False).export(source)
    result = {}
    for target in targets:
        out = folder / f"gltfpack_{target}.glb"
        started = time.perf_counter()
        subprocess.run([binary, "-i", str(source), "-o", str(out), "-si", f"{target / len(dense[1]):.6f}", "-noq"],
                       check=True, capture_output=True)
        seconds = time.perf_counter() - started
        mesh = trimesh.load(out, force="mesh", process=False)
        result[target] = (np.asarray(mesh.vertices), np.asarray(mesh.faces), seconds)
    return result


def fidelity(args) -> None:
    from sinshape.runtime import gltf

    model = load(args.model)
    up = model.manifest.up
    dense, colours, data, info = make_asset(model, args.seed, args.scale, args.lods, args.texture)
    document, binary = gltf.read(data)
    levels = [gltf.level_arrays(document, binary, k) for k in range(len(args.lods))]
    box = np.array([dense[0].min(axis=0), dense[0].max(axis=0)])
    with tempfile.TemporaryDirectory() as folder:
        others = {"Blender Decimate": decimated(dense, args.lods, Path(folder)),
                  "gltfpack -si": gltfpacked(dense, args.lods, Path(folder), args.gltfpack)}
    cameras = [Camera(box, view, up) for view in VIEWS]
    dense_albedo = vertex_albedo(dense[1], colours) if colours is not None else None
    references = [camera.draw(dense[0], dense[1], smooth_shading(*dense), dense_albedo) for camera in cameras]
    print(f"{args.model} seed {args.seed} scale {args.scale:g}: full mesh {len(dense[1])} triangles; maps "
          f"{args.texture}; {len(VIEWS)} views of {PICTURE_SIZE} px")
    print(f"{'triangles':>9} | {'what':<28} | {'silhouette IoU':>14} | {'brightness diff %':>17}")
    pictures = {}
    for k, target in enumerate(args.lods):
        arrays = levels[k]
        albedo = mapped_albedo(arrays) if arrays["colour_map"] is not None else None
        rows = {"asset: level + normal map": (arrays["position"], arrays["faces"], mapped_shading(arrays), albedo),
                "asset: level, no map": (*welded(arrays["position"], arrays["faces"]), None, None)}
        for name, made in others.items():
            if target in made:
                rows[name] = (*made[target][:2], None, None)
        for name, (vertices, faces, shading, colour) in rows.items():
            shading = shading or smooth_shading(vertices, faces)
            drawn = [camera.draw(vertices, faces, shading, colour) for camera in cameras]
            scores = np.array([compare(r, d) for r, d in zip(references, drawn)])
            print(f"{len(faces):>9} | {name:<28} | {scores[:, 0].mean():>14.4f} | {scores[:, 1].mean():>17.2f}")
            pictures[(target, name)] = drawn[0]
    if args.pictures:
        save_pictures(args, references[0], pictures)


def save_pictures(args, reference, pictures: dict) -> None:
    """One view: the full mesh, then per level a row of the asset with its map, without, and the others;
    and the first three of the coarsest level's row on their own (for the README)."""
    from PIL import Image, ImageDraw, ImageFont

    font = ImageFont.load_default(size=22)

    def tile(drawn, label):
        picture = Image.fromarray(np.round(drawn[2] * 255).astype(np.uint8))
        ImageDraw.Draw(picture).text((12, 10), label, fill=(20, 20, 20), font=font)
        return picture

    names = list(dict.fromkeys(name for _, name in pictures))
    for target in args.lods:
        row = [tile(reference, "full mesh")] + [tile(pictures[(target, n)], f"{n}, {target}")
                                                for n in names if (target, n) in pictures]
        sheet = Image.new("RGB", (PICTURE_SIZE * len(row), PICTURE_SIZE), "white")
        for i, picture in enumerate(row):
            sheet.paste(picture, (i * PICTURE_SIZE, 0))
        path = Path(args.pictures) / f"asset_{args.model}_{target}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        sheet.save(path)
        if target == args.lods[-1]:  # the full mesh beside the coarsest level with its maps and without
            sheet.crop((0, 0, 3 * PICTURE_SIZE, PICTURE_SIZE)).save(path.with_name(f"asset_{args.model}_three.png"))
        print(f"wrote {path}")


# --- speed and size --------------------------------------------------------------------------------------

BLENDER_BAKE = """
import sys, time, json
import numpy as np
sys.path.insert(0, {root!r})
import bpy
from blender import convert
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.cycles.samples = 1
scene.render.threads_mode = "FIXED"
scene.render.threads = {threads}
dense, low = np.load({dense!r}), np.load({low!r})
high = bpy.data.objects.new("high", bpy.data.meshes.new("high"))
convert.fill_mesh(high.data, dense["vertices"], dense["faces"], smooth_shading=True,
                  colours=dense["colours"] if "colours" in dense else None)
lowered = bpy.data.objects.new("low", bpy.data.meshes.new("low"))
convert.fill_mesh(lowered.data, low["vertices"], low["faces"], smooth_shading=True)
uv = lowered.data.uv_layers.new(name="UVMap")
texcoords = low["uvs"][low["faces"].ravel()].astype(np.float32)
texcoords[:, 1] = 1 - texcoords[:, 1]  # glTF's v runs down the image, Blender's up
uv.data.foreach_set("uv", texcoords.ravel())
for obj in (high, lowered):
    scene.collection.objects.link(obj)
material = bpy.data.materials.new("baked")
material.use_nodes = True
image = bpy.data.images.new("map", {size}, {size})
node = material.node_tree.nodes.new("ShaderNodeTexImage")
node.image = image
material.node_tree.nodes.active = node
lowered.data.materials.append(material)
if "colours" in dense:
    source = bpy.data.materials.new("vertex colour")
    source.use_nodes = True
    attribute = source.node_tree.nodes.new("ShaderNodeVertexColor")
    attribute.layer_name = "Col"
    source.node_tree.links.new(attribute.outputs["Color"], source.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    high.data.materials.append(source)
bpy.ops.object.select_all(action="DESELECT")
high.select_set(True)
lowered.select_set(True)
bpy.context.view_layer.objects.active = lowered
results = {{}}
bake = scene.render.bake
bake.use_selected_to_active = True
bake.cage_extrusion = {reach}
bake.margin = {margin}
for kind in ["NORMAL"] + (["DIFFUSE"] if "colours" in dense else []):
    if kind == "DIFFUSE":
        bake.use_pass_direct = bake.use_pass_indirect = False
        bake.use_pass_color = True
    started = time.perf_counter()
    bpy.ops.object.bake(type=kind, use_selected_to_active=True, cage_extrusion={reach}, margin={margin})
    results[kind] = time.perf_counter() - started
print("RESULT" + json.dumps(results))
"""


def speed(args) -> None:

    from sinshape.runtime import asset, gltf, write
    from sinshape.runtime.request import SampleRequest

    model = load(args.model)
    request = SampleRequest(args.seed, scale=args.scale)
    options = asset.AssetOptions(args.lods, args.texture or None, compress=args.compress)
    times = {"sample": [], "asset": []}
    write.request_bytes(model, request, "x.ply")  # the imports, untimed
    for _ in range(args.repeats):
        started = time.perf_counter()
        ply, mesh = write.request_bytes(model, request, "x.ply")
        times["sample"].append(time.perf_counter() - started)
        started = time.perf_counter()
        data, info = asset.asset_bytes(model, request, options, "sample")
        times["asset"].append(time.perf_counter() - started)
    best = {k: min(v) for k, v in times.items()}
    size = info["levels"][0]["texture"]
    print(f"{args.model} seed {args.seed} scale {args.scale:g}, lods {','.join(map(str, args.lods))}, maps "
          f"{size}{'' if args.texture else ' (sized to the sample)'}{', compressed' if args.compress else ''}: "
          f"best of {args.repeats}, alternated")
    print(f"  sample alone (.ply in memory)  {best['sample']:.2f} s   (runs: {', '.join(f'{t:.2f}' for t in times['sample'])})")
    print(f"  asset (.glb)                   {best['asset']:.2f} s   (runs: {', '.join(f'{t:.2f}' for t in times['asset'])})"
          f"  = {best['asset'] / best['sample']:.2f}x the sample; stages of the last: {info['seconds']}")
    dense_glb = write.mesh_bytes(mesh, ".glb")
    print(f"  size: asset {len(data) / 2**20:.2f} MB; the full mesh ({info['dense_triangles']} triangles) "
          f"{len(dense_glb) / 2**20:.2f} MB as .glb, {len(ply) / 2**20:.2f} MB as .ply "
          f"({len(dense_glb) / len(data):.1f}x, {len(ply) / len(data):.1f}x the asset)")
    document, binary = gltf.read(data)
    low = gltf.level_arrays(document, binary, 0)
    with tempfile.TemporaryDirectory() as folder:
        dense_path, low_path = Path(folder, "dense.npz"), Path(folder, "low.npz")
        colours = {"colours": np.asarray(mesh.visual.vertex_colors)[:, :3] / 255} if model.manifest.colour else {}
        np.savez(dense_path, vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces), **colours)
        np.savez(low_path, vertices=low["position"], faces=low["faces"], uvs=low["texcoord_0"])
        reach = max(level["error"] for level in info["levels"]) + 2 * max(model.manifest.spacing)
        result = blender(BLENDER_BAKE.format(root=str(ROOT), dense=str(dense_path), low=str(low_path),
                                             size=size, threads=2, reach=reach, margin=asset.padding(size)))
    if result is None:
        print("  Blender's bake: bpy is not installed")
        return
    total = sum(result.values())
    print(f"  Blender Cycles bake, selected to active, 1 sample, 2 threads: "
          f"{', '.join(f'{k.lower()} {v:.2f} s' for k, v in result.items())}; {total:.2f} s in all, "
          f"{total / info['seconds']['bake']:.2f}x the asset's bake ({info['seconds']['bake']:.2f} s) and "
          f"{total / best['asset']:.2f}x its whole asset ({best['asset']:.2f} s)")


BLENDER_RENDER = """
import bpy, math, json
from mathutils import Vector
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath={path!r})
meshes = [o for o in bpy.data.objects if o.type == "MESH"]
obj = meshes[0]  # the finest level (Blender imports the coarser ones too: hidden)
for other in meshes[1:]:
    other.hide_render = True
if not obj.data.materials:
    obj.data.materials.append(bpy.data.materials.new("clay"))
for polygon in obj.data.polygons:
    polygon.use_smooth = True
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.samples, scene.cycles.device = 16, "CPU"
scene.render.resolution_x = scene.render.resolution_y = {size}
corners = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
centre = sum(corners, Vector()) / 8
radius = max((c - centre).length for c in corners)
camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
scene.collection.objects.link(camera)
scene.camera = camera
camera.data.type, camera.data.ortho_scale = "ORTHO", 2.2 * radius
view = Vector((math.sin(math.radians(35)), -math.cos(math.radians(35)), 0.45)).normalized()
camera.location = centre + view * 4 * radius
camera.rotation_euler = (-view).to_track_quat("-Z", "Y").to_euler()
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
scene.collection.objects.link(sun)
sun.rotation_euler, sun.data.energy = (math.radians(50), 0, math.radians(-30)), 4
scene.world = bpy.data.worlds.new("world")
scene.world.color = (0.3, 0.3, 0.3)
scene.render.filepath = {out!r}
bpy.ops.render.render(write_still=True)
print("RESULT" + json.dumps({{"object": obj.name, "triangles": len(obj.data.polygons)}}))
"""


def cycles(args) -> None:
    """The full mesh and the coarsest level with its maps, rendered side by side by Blender's Cycles, which
    imports the .glb itself and builds its own tangents (MikkTSpace): the normal map read by an engine."""
    from PIL import Image

    from sinshape.runtime import write

    model = load(args.model)
    from sinshape.runtime.request import SampleRequest

    request = SampleRequest(args.seed, scale=args.scale)
    with tempfile.TemporaryDirectory() as folder:
        pictures = []
        for name, options in (("dense", None), ("asset", asset_options(args))):
            path = Path(folder, f"{name}.glb")
            write.write_request(model, request, path, asset=options)
            out = Path(folder, f"{name}.png")
            print(name, blender(BLENDER_RENDER.format(path=str(path), out=str(out), size=400)))
            pictures.append(Image.open(out).convert("RGB"))
        sheet = Image.new("RGB", (800, 400))
        for i, picture in enumerate(pictures):
            sheet.paste(picture, (400 * i, 0))
        Path(args.pictures).mkdir(parents=True, exist_ok=True)
        sheet.save(Path(args.pictures) / f"asset_{args.model}_cycles.png")
        print(f"wrote {Path(args.pictures) / f'asset_{args.model}_cycles.png'}")


def inside_hulls(points: np.ndarray, hulls: list) -> np.ndarray:
    """Which points lie inside some convex hull (within 1e-9 of its planes)."""
    inside = np.zeros(len(points), bool)
    for vertices, faces in hulls:
        corners = vertices[faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-30)
        offsets = np.einsum("ij,ij->i", normals, corners[:, 0])
        outward = np.sign(offsets - normals @ vertices.mean(axis=0))  # the centre lies inside every plane
        inside |= np.all((points @ normals.T - offsets) * outward <= 1e-9, axis=1)
    return inside


def hulls(args) -> None:
    from sinshape.runtime import SampleRequest, asset  # onnxruntime first: coacd 1.0.14 imported before it crashes

    import coacd

    coacd.set_log_level("off")
    rng = np.random.default_rng(0)
    print(f"seed {args.seed} scale {args.scale:g}; covered: share of the solid inside some hull; excess: the hulls' "
          "volume outside the solid, as a share of the solid's")
    print("| model | decomposition | seconds | hulls | covered | excess |")
    print("|---|---|---|---|---|---|")
    for name in args.models:
        model = load(name)
        dense = asset.dense_surface(model, SampleRequest(args.seed, scale=args.scale))
        low, high = dense.vertices.min(axis=0), dense.vertices.max(axis=0)
        points = low + rng.random((200_000, 3)) * (high - low)
        solid = dense.field.occupancy(dense.frame.to_model(points)) > 0.5
        source = asset.simplify(dense.vertices, dense.faces, asset.HULL_SOURCE, False)[:2]
        runs = [(f"at most {n}", lambda n=n: asset.convex_hulls(dense.vertices, dense.faces, n)) for n in (8, 16, 32)]
        runs.append(("at most 16, CoACD's defaults", lambda: [
            (np.asarray(v), np.asarray(f)) for v, f in coacd.run_coacd(coacd.Mesh(*source), max_convex_hull=16, seed=0)]))
        try:
            import vhacdx  # V-HACD's bindings (the one trimesh calls), for the comparison: pip install vhacdx
            runs.append(("at most 16, V-HACD (vhacdx)", lambda: [
                (np.asarray(v), np.asarray(f, np.int64))
                for v, f in vhacdx.compute_vhacd(source[0], source[1].astype(np.uint32), maxConvexHulls=16)]))
        except ImportError:
            pass
        for label, run in runs:
            started = time.perf_counter()
            made = run()
            seconds = time.perf_counter() - started
            inside = inside_hulls(points, made)
            print(f"| {name} | {label} | {seconds:.1f} | {len(made)} | {np.mean(inside[solid]):.3f} | "
                  f"{np.sum(inside & ~solid) / max(np.sum(solid), 1):.3f} |", flush=True)


def base(args) -> None:
    from sinshape.runtime import SampleRequest, asset, bake

    print(f"seed {args.seed} scale {args.scale:g}, a {args.lods[0]}-triangle level, maps {args.texture}")
    print("| model | base faces | atlas filled, base charted with the rest / apart | the base's share of the filled "
          "texels | texels per area of the rest, apart / with |")
    print("|---|---|---|---|---|")
    for name in args.models:
        model = load(name)
        dense = asset.dense_surface(model, SampleRequest(args.seed, scale=args.scale))
        vertices, faces, _ = asset.simplify(dense.vertices, dense.faces, args.lods[0], False)
        unseen = asset.on_the_ground(vertices, faces, dense.up, dense.voxel)
        index = {tuple(sorted(face)): k for k, face in enumerate(faces.tolist())}
        figures = []
        for mask in (None, unseen):
            source, split, uvs = asset.unwrap(vertices, faces, args.texture, mask)
            texels, owner, _ = bake.rasterise_uv(uvs, split, args.texture)
            on_base = unseen[[index[tuple(sorted(face))] for face in source[split].tolist()]][owner]
            figures.append((len(texels) / args.texture ** 2, on_base.mean(),
                            np.sum(~on_base) / bake.area(vertices[faces[~unseen]]).sum()))
        (filled, share, density), (filled_apart, share_apart, density_apart) = figures
        print(f"| {name} | {unseen.sum()} of {len(faces)} | {filled:.2f} / {filled_apart:.2f} | {share:.3f} / "
              f"{share_apart:.4f} | {density_apart / density:.2f}x |", flush=True)


def size(args) -> None:
    """Each model's asset at --scale and --lods: maps sized to the sample
    (floats, quantised, compressed) and at --texture, against the plain
    sample's .glb (the full mesh), whole files and their geometry alone."""
    from sinshape.runtime import SampleRequest, asset, gltf, write

    kinds = [dict(), dict(quantise=True), dict(compress=True), dict(texture=args.texture)]
    heads = ["floats", "quantised", "compressed", f"floats, {args.texture} maps"]
    if shutil.which("basisu"):  # Basis Universal's encoder: the maps as KTX2 too
        kinds += [dict(ktx2=True), dict(ktx2=True, compress=True)]
        heads += ["KTX2 maps", "KTX2 maps, compressed"]
    print(f"seed {args.seed} scale {args.scale:g}, lods {','.join(map(str, args.lods))}; MB, whole file (geometry); "
          "the maps' GPU memory, MB (PNG: RGBA8, KTX2: BC7, each with mip-maps)")
    print(f"| model | full mesh .glb | sized maps | {' | '.join(heads)} | maps' GPU memory, PNG / KTX2 |")
    print("|---|---|---|" + "---|" * len(heads) + "---|")
    for name in args.models:
        model = load(name)
        request = SampleRequest(args.seed, scale=args.scale)
        dense = len(write.request_bytes(model, request, "x.glb")[0])
        cells, sized = [], None
        for kind in kinds:
            data, info = asset.asset_bytes(model, request, asset.AssetOptions(args.lods, **kind), name)
            document, _ = gltf.read(data)
            maps = sum(document["bufferViews"][image["bufferView"]]["byteLength"] for image in document["images"])
            cells.append(f"{len(data) / 1e6:.2f} ({(len(data) - maps) / 1e6:.2f})")
            if sized is None:  # the first: maps sized to the sample, whose texels the GPU holds
                sized = info["levels"][0]["texture"]
                texels = len(document["images"]) // len(info["levels"]) * sum(f["texture"] ** 2 for f in info["levels"])
        print(f"| {name} | {dense / 1e6:.2f} | {sized} | {' | '.join(cells)} | {texels * 4 * 4 / 3 / 1e6:.1f} / "
              f"{texels * 4 / 3 / 1e6:.1f} |", flush=True)


def engines(args) -> None:
    """Each model's asset at the defaults (--lods, maps sized to the sample,
    the coarsest level as its collision) for --seeds at --scale, as the
    importers read it (tools/importers.py): the Khronos validator's errors
    and warnings, and what Godot 3 and Babylon.js make of it (meshes drawn,
    collision shapes), one row a model; a tool not installed is a dash."""
    sys.path.insert(0, str(ROOT / "tools"))
    import importers

    from sinshape.runtime import SampleRequest, asset

    seeds = range(args.seeds)
    print(f"seeds 0-{args.seeds - 1}, scale {args.scale:g}, lods {','.join(map(str, args.lods))}, maps sized; "
          "each cell: what the seeds gave, and how many gave it")
    print("| model | validator errors / warnings (all seeds) | Godot 3: meshes drawn; collision shapes | "
          "Babylon.js: meshes drawn |")
    print("|---|---|---|---|")
    for name in args.models:
        model = load(name)
        issues, godot, babylon = [0, 0], {}, {}
        with tempfile.TemporaryDirectory() as folder:
            for seed in seeds:
                path = Path(folder, f"{name}_{seed}.glb")
                data, info = asset.asset_bytes(model, SampleRequest(seed, scale=args.scale),
                                               asset.AssetOptions(args.lods), name)
                path.write_bytes(data)
                report = importers.validator_report(path)
                if report is not None:
                    issues[0] += report["issues"]["numErrors"]
                    issues[1] += report["issues"]["numWarnings"]
                found = importers.godot_scene(path, Path(folder, f"godot{seed}"))
                if found is not None:
                    coarsest = info["levels"][-1]["triangles"]
                    shapes = [f"{c['body']} {c['shape']}" + (" of the coarsest level" if c["triangles"] == coarsest else "")
                              for c in found["collision"]]
                    key = f"{', '.join(m['name'].split('_')[-1] for m in found['meshes'])}; {', '.join(shapes) or 'none'}"
                    godot[key] = godot.get(key, 0) + 1
                found = importers.babylon_scene(path)
                if found is not None:
                    key = ", ".join(m["name"].split("_")[-1] for m in found["meshes"])
                    babylon[key] = babylon.get(key, 0) + 1

        def cell(counts):
            return " / ".join(f"{key} (x{n})" for key, n in counts.items()) or "-"
        print(f"| {name} | {issues[0]} / {issues[1]} | {cell(godot)} | {cell(babylon)} |", flush=True)


def asset_options(args):
    from sinshape.runtime import asset

    return asset.AssetOptions(args.lods[-1:], args.texture)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["fidelity", "speed", "cycles", "hulls", "base", "size", "engines"])
    parser.add_argument("--models", nargs="+", default=["towerruins", "acropolis", "terrain", "brickruin"])
    parser.add_argument("--model", default="towerruins")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--scale", type=float, default=4.0)
    parser.add_argument("--lods", default=None, help="Default: 20000,5000,1200 (fidelity), 5000 (speed).")
    parser.add_argument("--texture", type=int, default=2048, help="0: sized to the sample (speed), as without --texture")
    parser.add_argument("--compress", action="store_true", help="speed: the geometry compressed (EXT_meshopt_compression)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=10, help="engines: seeds 0 to N-1")
    parser.add_argument("--gltfpack", default=None)
    parser.add_argument("--pictures", default=None)
    args = parser.parse_args()
    args.lods = tuple(int(n) for n in (args.lods or ("5000" if args.what in ("speed", "base") else "20000,5000,1200"))
                      .split(","))
    {"fidelity": fidelity, "speed": speed, "cycles": cycles, "hulls": hulls, "base": base, "size": size,
     "engines": engines}[args.what](args)


if __name__ == "__main__":
    main()
