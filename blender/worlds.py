"""A world object: the tiles of an endless world (runtime.world) around a
point that it follows, made off the main thread, those left behind dropped.

The world object is an Empty; the world lies in its space (tile (0, 0)'s
corner where the model's frame puts it, turned to Z up as a sample is), so
moving, turning or scaling it moves the whole world. It follows its
`follow` object (the camera, say), or the 3D cursor where none is set.

One child mesh object per tile, not one joined mesh: each tile is made on
its own (world.tile_surface) and shown as soon as it is done, a tile left
behind is one object removed, and nothing already shown is rebuilt when
the point moves on; a joined mesh would be rebuilt whole for every tile
that comes or goes. The runtime's tiles share their border vertices
exactly, so side by side they are one surface without a weld. Tiles past
the fine radius are made a level coarser per tile (world.WorldOptions.lod),
with the skirt that covers the crack where they meet finer ones, and made
again at their new level as the point moves.
"""

import math

import bpy
import numpy as np

from sinshape.core.errors import InputError
from sinshape.runtime import world

from . import convert, live, work

TILE = "sinshape_tile"  # a tile object's custom property: "I,J"
MADE = "sinshape_made"  # ... and what it was made from: the model file's SHA-256, the seed, the scale, the arrangement, its lod


def followed_point(obj, scene) -> np.ndarray:
    """The point a world follows, in the world object's space (Blender's axes)."""
    follow = obj.sinshape_world.follow
    location = follow.matrix_world.translation if follow is not None else scene.cursor.location
    return np.array(obj.matrix_world.inverted() @ location, float)


def centre_tile(model, layout: world.Layout, point) -> tuple:
    """The tile (i, j) holding a point given in the world object's space."""
    manifest = model.manifest
    voxels = (convert.to_model([point], manifest.up)[0] - np.asarray(manifest.origin)) / np.asarray(manifest.spacing)
    along = [voxels[axis] / layout.stride[axis] for axis in layout.horizontal]
    if not all(math.isfinite(value) and abs(value) < world.MAX_TILE for value in along):
        raise InputError("the followed point lies beyond the world's last tile (2**62 tiles from its origin)",
                         "follow")
    return tuple(math.floor(value) for value in along)


def tiles_around(centre, radius: int) -> list:
    """The (2 radius + 1)^2 tiles centred on `centre`, the nearest first."""
    ci, cj = centre
    tiles = [world.check_tile((ci + di, cj + dj)) for di in range(-radius, radius + 1)
             for dj in range(-radius, radius + 1)]
    return sorted(tiles, key=lambda t: (max(abs(t[0] - ci), abs(t[1] - cj)), t))


def detail(centre, tile, fine: int, coarsest: int) -> int:
    """The level of detail of a tile: 0 within `fine` tiles of the centre's, a level coarser per tile beyond."""
    return min(coarsest, max(0, max(abs(tile[0] - centre[0]), abs(tile[1] - centre[1])) - fine))


def tile_objects(obj) -> dict:
    """(i, j) -> the world's child object holding that tile."""
    return {tuple(int(n) for n in child[TILE].split(",")): child for child in obj.children if TILE in child}


def remove(child) -> None:
    mesh = child.data
    bpy.data.objects.remove(child)
    if mesh is not None and not mesh.users:
        bpy.data.meshes.remove(mesh)


def refresh(obj, scene=None, force: bool = False) -> None:
    """Fill the tiles around the point a world follows: tiles beyond its
    radius are dropped at once, those missing (or made from other settings;
    every one if `force`) are made, the nearest first: at once in
    background mode, else off the main thread, each shown as it is done.
    What is wrong before the work raises InputError, also written on the
    object. Nothing is done when the tiles and settings asked for are those
    asked for last."""
    settings = obj.sinshape_world
    scene = scene or bpy.context.scene
    try:
        model, digest = live.load_settings(settings)
        layout = world.world_layout(model)
        world.check_world_scale(layout, settings.scale, model.manifest.hidden, None)
        centre = centre_tile(model, layout, followed_point(obj, scene))
        wanted = tiles_around(centre, settings.radius)
        made = f"{digest}:{settings.seed}:{settings.scale!r}:{settings.arrange}"
        lods = {tile: detail(centre, tile, settings.fine, len(model.manifest.sizes) - 1) for tile in wanted}
        if not force and live.MADE.get(obj.name) == (made, lods):
            return
        live.MADE[obj.name] = (made, lods)
        present = tile_objects(obj)
        for tile in set(present) - set(wanted):
            remove(present.pop(tile))
        todo = [(tile, lods[tile]) for tile in wanted
                if force or tile not in present or present[tile].get(MADE) != f"{made}:{lods[tile]}"]
        settings.error = ""
        if todo:
            submit(obj.name, model, made, settings.seed, settings.scale, settings.arrange, todo)
    except InputError as error:
        settings.error = str(error)
        raise


def submit(name: str, model, made: str, seed: int, scale: float, arrange: str, tiles: list) -> None:
    """One job for a world's tiles ((tile, level of detail) pairs); a newer one for the same world stops
    it between two tiles."""
    up = model.manifest.up

    def compute(job):
        for done, (tile, lod) in enumerate(tiles):
            job.progress(done, len(tiles))
            surface = world.tile_surface(model, seed, tile, scale, world.WorldOptions(arrange, lod=lod))
            colours = None if surface.colours is None else convert.byte_colours(surface.colours)
            arrays = live.blender_arrays(world.placed(model, tile, surface.vertices, "tile"), surface.faces, up, colours)
            job.deliver((tile, f"{made}:{lod}", arrays))

    def fail(error):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            obj.sinshape_world.error = str(error)
        live.report_later(f"{name}: {error}")

    work.WORKER.submit(work.Job(name, f"{name}: {len(tiles)} tiles", compute,
                                lambda result: apply_tile(name, model, *result), fail))


def apply_tile(name: str, model, tile: tuple, made: str, arrays) -> None:
    """A finished tile into its child object (made where there is none), placed at the tile's corner."""
    obj = bpy.data.objects.get(name)
    if obj is None or not obj.sinshape_world.active:
        return
    child = tile_objects(obj).get(tile)
    if child is None:
        label = f"{name} tile {tile[0]},{tile[1]}"
        child = bpy.data.objects.new(label, bpy.data.meshes.new(label))
        child[TILE] = f"{tile[0]},{tile[1]}"
        for collection in obj.users_collection:
            collection.objects.link(child)
        child.parent = obj
        manifest = model.manifest
        corner = np.asarray(manifest.origin) + np.array(world.tile_corner(model, tile)) * np.asarray(manifest.spacing)
        child.location = convert.to_blender([corner], manifest.up)[0]
    live.put_mesh(child.data, arrays, True)
    child[MADE] = made


def world_of(obj):
    """The world an object is, or is a tile of; None."""
    if obj is not None and obj.sinshape_world.active:
        return obj
    if obj is not None and TILE in obj and obj.parent is not None and obj.parent.sinshape_world.active:
        return obj.parent
    return None


def changed(settings, context) -> None:
    """A world setting's update: refill its tiles; an error goes on the object and in a report."""
    if live.SUSPENDED or not settings.active:
        return
    obj = settings.id_data
    try:
        refresh(obj, context.scene)
    except InputError as error:
        live.report_later(f"{obj.name}: {error}")


def follow(scene, moved: set, scene_changed: bool) -> None:
    """After a change in the scene (`moved`: the names of objects that
    moved): worlds whose followed point may have moved (the followed
    object, the world itself, or the 3D cursor, which changes the scene)
    fill their tiles around it; quietly, as a drag goes."""
    for obj in [obj for obj in scene.objects if obj.sinshape_world.active]:  # a list: refresh removes objects
        target = obj.sinshape_world.follow
        if (target is None and scene_changed) or {obj.name, target.name if target else obj.name} & moved:
            try:
                refresh(obj, scene)
            except InputError:
                pass  # recorded on the object; no report for each step of a drag


def opened() -> None:
    """After a file opens: each world's model checked and its missing tiles made."""
    for obj in bpy.data.objects:
        if obj.sinshape_world.active:
            try:
                refresh(obj, bpy.context.scene)
            except InputError as error:
                live.report_later(f"{obj.name}: {error}", "WARNING")
