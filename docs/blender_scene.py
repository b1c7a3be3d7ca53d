"""docs/blender.png: variations of a shipped model, made by the Blender
extension and rendered by Blender itself (Cycles, headless).

    python docs/blender_scene.py [--model towerruins] [--count 6] [--samples 64] [-o docs/blender.png]

Needs bpy (pip install 'sinshape[blender]'). The sample and its variations
come from the add-on's own operators, as a user would make them; the rest
is staging: a ground, a sun and sky, a camera framing them all.
"""

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402
from mathutils import Vector  # noqa: E402

import blender  # noqa: E402


def material(name: str, colour, roughness: float):
    made = bpy.data.materials.new(name)
    made.use_nodes = True
    shader = made.node_tree.nodes["Principled BSDF"]
    shader.inputs["Base Color"].default_value = (*colour, 1.0)
    shader.inputs["Roughness"].default_value = roughness
    return made


def samples(model: str, count: int, smooth: int):
    """The add-on's sample and its variations, in a grid on the ground."""
    bpy.ops.sinshape.add_sample(model=model, seed=0, scale=2, smooth=smooth)
    first = bpy.context.active_object
    bpy.ops.sinshape.variations(count=count - 1, first_seed=1, arrange="GRID")
    made = [first, *bpy.data.collections[f"{first.name} variations"].objects]
    stone = [material(f"stone {k}", colour, 0.85) for k, colour in
             enumerate([(0.42, 0.36, 0.3), (0.36, 0.34, 0.31), (0.45, 0.39, 0.32)])]
    for k, obj in enumerate(made):
        obj.data.materials.append(stone[k % len(stone)])
        obj.location.z -= min(corner[2] for corner in obj.bound_box)  # stand on the ground
    return made


def stage(objects, width: int, height: int, samples_per_pixel: int) -> None:
    corners = np.array([obj.matrix_world @ Vector(corner) for obj in objects for corner in obj.bound_box])
    low, high = corners.min(axis=0), corners.max(axis=0)
    centre, extent = (low + high) / 2, high - low
    bpy.ops.mesh.primitive_plane_add(size=1, location=(centre[0], centre[1], 0))
    ground = bpy.context.active_object
    ground.scale = (extent[0] * 30, extent[1] * 30, 1)
    ground.data.materials.append(material("ground", (0.16, 0.15, 0.13), 0.95))

    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 2.5
    sun.data.angle = math.radians(4)
    sun.rotation_euler = (math.radians(50), 0, math.radians(30))
    bpy.context.scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    sky = world.node_tree.nodes.new("ShaderNodeTexSky")
    world.node_tree.links.new(sky.outputs["Color"], world.node_tree.nodes["Background"].inputs["Color"])
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.25
    bpy.context.scene.world = world

    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.data.lens = 50
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.scene.camera = camera
    direction = Vector((0.5, -1.0, 0.62)).normalized()
    target = Vector(centre)
    camera.location = target + direction * float(np.linalg.norm(extent)) * 2.1
    camera.rotation_euler = (target - camera.location).to_track_quat("-Z", "Y").to_euler()

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples_per_pixel
    scene.cycles.use_denoising = True
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.view_settings.view_transform = "AgX"
    scene.view_settings.look = "AgX - Medium High Contrast"
    scene.view_settings.exposure = -1.3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="towerruins")
    parser.add_argument("--count", type=int, default=6)
    parser.add_argument("--smooth", type=int, default=1)
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--size", type=int, nargs=2, default=(1280, 640))
    parser.add_argument("-o", "--output", type=Path, default=ROOT / "docs" / "blender.png")
    args = parser.parse_args()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender.register()
    stage(samples(args.model, args.count, args.smooth), *args.size, args.samples)
    bpy.context.scene.render.filepath = str(args.output.resolve())
    bpy.ops.render.render(write_still=True)
    from PIL import Image  # 256 colours, dithered: a third of the bytes, the same picture to the eye

    picture = Image.open(args.output).convert("RGB")
    picture.quantize(256, Image.Quantize.MEDIANCUT, dither=Image.Dither.FLOYDSTEINBERG).save(args.output, optimize=True)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
