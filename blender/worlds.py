"""A world object: the tiles of an endless world (runtime.world) around a
point that it follows, made off the main thread, those left behind dropped.

The world object is an Empty; the world lies in its space (tile (0, 0)'s
corner where the model's frame puts it, turned to Z up as a sample is), so
moving, turning or scaling it moves the whole world. It follows its
`follow` object (the camera, say), or the 3D cursor where none is set.

One child mesh object per tile, not one joined mesh: each tile is made on
its own (world_tiles.tile_surface) and shown as soon as it is done, a tile left
behind is one object removed, and nothing already shown is rebuilt when
the point moves on; a joined mesh would be rebuilt whole for every tile
that comes or goes. The runtime's tiles share their border vertices
exactly, so side by side they are one surface without a weld. Tiles past
the fine radius are made a level coarser per tile (world.WorldOptions.lod),
with the skirt that covers the crack where they meet finer ones, and made
again at their new level as the point moves.
"""

import dataclasses
import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import check_readable
from sinshape.runtime import generate, world, world_maps, world_tiles

from . import convert, live, work

TILE = "sinshape_tile"  # a tile object's custom property: "I,J"
MADE = "sinshape_made"  # ... and what it was made from: the model file's SHA-256, the seed, the scale, the
# arrangement, the other models' SHA-256s, the model map's and height map's pixels' SHA-256s, the density
# and spacing, the detail, its lod
MAX_RADIUS = 32  # tiles on each side: (2 r + 1)^2 = 4225 tiles at most
# (what, path, size, mtime, relief) -> (world_maps.ModelMap or HeightMap, its pixels' SHA-256): a map is read again
# only when it changed
MAPS = {}
KEEP_MAPS = 4


def followed_point(obj, scene) -> np.ndarray:
    """The point a world follows, in the world object's space (Blender's axes)."""
    follow = obj.sinshape_world.follow
    location = follow.matrix_world.translation if follow is not None else scene.cursor.location
    return np.array(obj.matrix_world.inverted() @ location, float)


def centre_tile(model, tiling: world.Tiling, point) -> tuple:
    """The tile (i, j) holding a point given in the world object's space."""
    manifest = model.manifest
    voxels = (convert.to_model([point], manifest.up)[0] - np.asarray(manifest.origin)) / np.asarray(manifest.spacing)
    along = [voxels[axis] / tiling.stride[axis] for axis in tiling.horizontal]
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
    """The level of detail of a tile: 0 within `fine` tiles of the centre's, a level coarser per tile beyond,
    down to `coarsest` (world.farthest_lod: not the sketch)."""
    return min(coarsest, max(0, max(abs(tile[0] - centre[0]), abs(tile[1] - centre[1])) - fine))


TILE_TEXT = re.compile(r"(-?[0-9]{1,19}),(-?[0-9]{1,19})")


def tile_of(child) -> tuple:
    """The tile (i, j) a child object holds, as its TILE property says
    ("I,J"), checked as the runtime checks a tile."""
    value = child[TILE]
    match = TILE_TEXT.fullmatch(value) if isinstance(value, str) else None
    if match is None:
        raise InputError(f"{child.name}: its {TILE} property {str(value)[:40]!r} is not a tile I,J (two "
                         "integers): remove the property or the object", "tile")
    return world.check_tile((int(match[1]), int(match[2])))


def tile_objects(obj) -> dict:
    """(i, j) -> the world's child object holding that tile."""
    return {tile_of(child): child for child in obj.children if TILE in child}


def check_settings(settings) -> None:
    """What a world's settings hold (a .blend may hold anything) before use:
    the seed as the runtime checks it, and the radius within its property's bounds."""
    generate.check_seed(settings.seed)
    radius = settings.radius
    if not 0 <= radius <= MAX_RADIUS:
        raise InputError(f"`radius` must be 0 to {MAX_RADIUS} tiles on each side, got {radius}", "radius")


def read_map(reference: str, what: str, read, relief: float = 0.0) -> tuple:
    """(the map a world's map setting names ('//' relative to the .blend),
    read by the runtime's reader `read(path)`, its pixels' SHA-256); (None,
    '') where none is named. Read once while the file (and the relief) is unchanged."""
    if not reference.strip():
        return None, ""
    path = check_readable(Path(bpy.path.abspath(reference)), what)
    stat = path.stat()
    key = (what, str(path), stat.st_size, stat.st_mtime_ns, relief)
    if key not in MAPS:
        if len(MAPS) >= KEEP_MAPS:
            MAPS.pop(next(iter(MAPS)))
        found = read(path)
        MAPS[key] = found, hashlib.sha256(repr(found.shape).encode() + found.data).hexdigest()
    return MAPS[key]


def world_options(settings, model, digest: str) -> tuple:
    """(the world.WorldOptions a world's settings stand for (`model`, its
    first, measures an image height map's white), checked by the runtime as
    the command line's are; what its tiles are made from: the
    first model's SHA-256 (`digest`), the seed, the scale, the arrangement,
    the other models' SHA-256s, the maps', the density, spacing and detail)."""
    others = [live.load_settings(other) for other in settings.models]
    placed, placed_digest = read_map(settings.models_map, "model map", world_maps.read_model_map)
    relief = settings.relief or None  # 0: an image's white is world_maps.RELIEF times the model's height
    heights, heights_digest = read_map(settings.heights, "height map",
                                       lambda path: world_maps.read_height_map(path, model, relief), settings.relief)
    values = convert.table_values(settings, convert.WORLD_TABLE_SETTINGS)
    scattered = {"density": values["density"], "spacing": values["spacing"]} if values["arrange"] == "scatter" else {}
    options = world.WorldOptions(values["arrange"], heights=heights, models=tuple(each for each, _ in others),
                                 models_map=placed, detail=values["detail"], **scattered, **convert.FIXED)
    made = (f"{digest}:{values['seed']}:{values['scale']!r}:{values['arrange']}:"
            f"{','.join(each for _, each in others)}:{placed_digest}:{heights_digest}:{options.density!r}:"
            f"{options.spacing!r}:{options.detail}")
    return options, made


def remove(child) -> None:
    if child.parent is not None and TILE in child:
        try:
            SHADES.get(child.parent.name, {}).pop(tile_of(child), None)
        except InputError:
            pass  # a child that names no tile has no shade
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
        check_settings(settings)
        model, digest = live.load_settings(settings)
        options, made = world_options(settings, model, digest)
        tiling = world.world_tiling(model)
        scale = convert.typed(settings.scale)
        world.check_world_scale(tiling, scale, world.hidden_width(model, options), None)
        centre = centre_tile(model, tiling, followed_point(obj, scene))
        wanted = tiles_around(centre, settings.radius)
        lods = {tile: detail(centre, tile, settings.fine, world.farthest_lod(model)) for tile in wanted}
        if not force and live.MADE.get(obj.name) == (made, lods):
            return
        live.MADE[obj.name] = (made, lods)
        present = tile_objects(obj)
        todo = [(tile, lods[tile]) for tile in wanted
                if force or tile not in present or present[tile].get(MADE) != f"{made}:{lods[tile]}"]
        # Tiles left behind stay until the new ones are made (a jump would
        # show nothing for seconds), the farthest dropped at once past as many as are wanted.
        centre = wanted[0]
        behind = sorted(set(present) - set(wanted), key=lambda t: -max(abs(t[0] - centre[0]), abs(t[1] - centre[1])))
        for tile in behind[:max(0, len(behind) - len(wanted)) if todo else None]:
            remove(present.pop(tile))
        settings.error = far_warning(model, wanted)
        if todo:
            submit(obj.name, model, made, settings.seed, scale, options, todo)
    except InputError as error:
        settings.error = str(error)
        live.MADE.pop(obj.name, None)  # the next asking is made, even one the same as the last made
        raise


# A crack between tiles that float32 locations may open, in voxels, beyond
# which the world object says so.
VISIBLE_CRACK = 0.01


def far_warning(model, tiles: list) -> str:
    """What to say where tiles lie so far from the world object's origin that
    their 32-bit locations (Blender keeps no other) step by more than
    VISIBLE_CRACK of a voxel, opening cracks between them; else ''."""
    manifest = model.manifest
    voxel = float(np.min(manifest.spacing))
    corners = [np.asarray(manifest.origin) + np.array(world_tiles.tile_corner(model, tile)) * np.asarray(manifest.spacing)
               for tile in (tiles[0], tiles[-1])]  # the centre and the farthest
    far = float(max(np.abs(corner).max() for corner in corners))
    step = float(np.spacing(np.float32(far)))
    if step <= VISIBLE_CRACK * voxel:
        return ""
    limit = VISIBLE_CRACK * voxel * 2.0**23
    return (f"tiles here lie {far:.3g} units from the world object's origin, where Blender's 32-bit locations "
            f"step by {step:.2g} units ({step / voxel:.2g} voxels): cracks open between tiles beyond about "
            f"{limit:.3g} units. Move the world object near them")


def submit(name: str, model, made: str, seed: int, scale: float, options, tiles: list) -> None:
    """One job for a world's tiles ((tile, level of detail) pairs) of a world made as `options` say (its
    lod aside); a newer one for the same world stops it between two tiles."""
    up = model.manifest.up

    def compute(job):
        for done, (tile, lod) in enumerate(tiles):
            job.progress(done, len(tiles))
            surface = world_tiles.tile_surface(model, seed, tile, scale, dataclasses.replace(options, lod=lod))
            colours = None if surface.colours is None else convert.byte_colours(surface.colours)
            arrays = live.blender_arrays(world_tiles.placed(model, tile, surface.vertices, "tile"), surface.faces, up, colours)
            job.deliver((f"{made}:{lod}", tile, arrays, tile_shade(model, tile, arrays[0], surface.faces)))
        job.deliver(None)  # all made: the tiles left behind go

    def fail(error):
        obj = bpy.data.objects.get(name)
        if obj is not None:
            obj.sinshape_world.error = str(error)
        live.report_later(f"{name}: {error}")

    def apply(result):
        if result is None:
            drop_behind(name)
        else:
            apply_tile(name, model, *result)

    work.WORKER.submit(work.Job(name, f"{name}: {len(tiles)} tiles", compute, apply, fail))


def drop_behind(name: str) -> None:
    """Remove a world's tiles that its last asking does not want."""
    obj = bpy.data.objects.get(name)
    if obj is None or name not in live.MADE:
        return
    wanted = set(live.MADE[name][1])
    for tile, child in tile_objects(obj).items():
        if tile not in wanted:
            remove(child)


def apply_tile(name: str, model, made: str, tile: tuple, arrays, shade) -> None:
    """A finished tile into its child object (made where there is none),
    placed at the tile's corner, its normals and its neighbours' made to
    agree along their borders (`shade_borders`)."""
    obj = bpy.data.objects.get(name)
    if obj is None or not obj.sinshape_world.active:
        return
    try:
        child = tile_objects(obj).get(tile)
    except InputError as error:  # a child renamed while the work ran
        obj.sinshape_world.error = str(error)
        return
    if child is None:
        label = f"{name} tile {tile[0]},{tile[1]}"
        child = bpy.data.objects.new(label, bpy.data.meshes.new(label))
        child[TILE] = f"{tile[0]},{tile[1]}"
        for collection in obj.users_collection:
            collection.objects.link(child)
        child.parent = obj
        manifest = model.manifest
        corner = np.asarray(manifest.origin) + np.array(world_tiles.tile_corner(model, tile)) * np.asarray(manifest.spacing)
        child.location = convert.to_blender([corner], manifest.up)[0]
    live.put_mesh(child.data, arrays, True)
    child[MADE] = made
    SHADES.setdefault(name, {})[tile] = shade
    shade_borders(obj, model, tile)


# Normals that agree along tile borders. A tile's own faces give a vertex
# on its border half of the faces around it, which shades each border as a
# crease; the tiles beside it give the rest. Each vertex's sum of its
# faces' normals, weighted by the face's angle at it as Blender weighs them,
# is kept with the tile under where the vertex lies on a border line (its
# place there is the same bits in both tiles), and a border vertex's
# normal is the sum over the tiles present there, set as a custom normal;
# the others keep Blender's own. A world's page does the same.
SHADES = {}  # world name -> {tile: Shade}


@dataclass
class Shade:
    sums: np.ndarray  # (n, 3) float64: each vertex's angle-weighted face normals, summed
    borders: dict  # where a border vertex lies (border_key) -> its index


def tile_shade(model, tile: tuple, vertices, faces) -> Shade:
    """A tile's Shade, from its mesh as Blender holds it (float32, its own
    space along Blender's axes). A skirt's faces (those lying in one of the
    tile's sides, hanging from its border) are left out of the sums, so
    that a border vertex shades as the surface it borders."""
    vertices = np.asarray(vertices, np.float32).astype(np.float64)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    _, sides, _ = tile_sides(model, np.asarray(vertices, np.float32))
    in_a_side = np.zeros(len(faces), bool)
    for side in sides:
        for end in (1, 2):
            in_a_side |= (side[faces] == end).all(axis=1)
    faces = faces[~in_a_side]
    sums = np.zeros_like(vertices)
    if len(faces):
        corners = vertices[faces]  # (m, 3 corners, 3)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        for k in range(3):
            a, b = corners[:, (k + 1) % 3] - corners[:, k], corners[:, (k + 2) % 3] - corners[:, k]
            cosine = (a * b).sum(axis=1) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300)
            angle = np.arccos(np.clip(cosine, -1, 1))
            for axis in range(3):
                sums[:, axis] += np.bincount(faces[:, k], normal[:, axis] * angle, len(vertices))
    return Shade(sums, border_keys(model, tile, np.asarray(vertices, np.float32)))


def tile_sides(model, vertices: np.ndarray) -> tuple:
    """Where a tile's vertices lie on its sides: (the Blender axis of each
    of the two horizontal model axes, per axis 1 for a vertex on its low
    side, 2 on its high side, 0 on neither, and Blender's up axis)."""
    tiling = world.world_tiling(model)
    manifest = model.manifest
    turn = convert.TURNS[manifest.up]
    axes, sides = [], []
    for a in tiling.horizontal:  # model axis a lies along Blender axis b, in direction sign
        b = int(np.abs(turn[:, a]).argmax())
        axes.append(b)
        end = float(np.float32(turn[b, a] * tiling.stride[a] * manifest.spacing[a]))
        sides.append((vertices[:, b] == 0) * 1 + (vertices[:, b] == end) * 2)  # 1 low, 2 high, 0 neither
    return axes, sides, int(np.abs(turn[:, tiling.up]).argmax())


def border_keys(model, tile: tuple, vertices: np.ndarray) -> dict:
    """Where each of a tile's vertices on its four sides lies: ('a', line,
    j, ...) on a line between two columns of tiles, ('b', i, line, ...)
    between two rows, ('c', line, line, up) on a corner's column, with its
    coordinates along the line, as the tile's neighbours name it too."""
    (b0, b1), (s0, s1), up = tile_sides(model, vertices)
    i, j = tile
    keys = {}
    for index in np.flatnonzero((s0 > 0) | (s1 > 0)):
        line0, line1 = i + (s0[index] == 2), j + (s1[index] == 2)
        v = vertices[index].tolist()
        key = (("c", line0, line1, v[up]) if s0[index] and s1[index] else
               ("a", line0, j, v[b1], v[up]) if s0[index] else ("b", i, line1, v[b0], v[up]))
        keys[key] = index
    return keys


def shade_borders(obj, model, tile: tuple) -> None:
    """A tile that came: its normals and those of the tiles beside it, summed along their shared borders."""
    present = tile_objects(obj)
    shades = SHADES.setdefault(obj.name, {})
    for other, child in present.items():  # tiles from a saved file: their shade from their mesh
        if other not in shades and max(abs(other[0] - tile[0]), abs(other[1] - tile[1])) <= 2:
            vertices, faces = convert.mesh_arrays(child.data)
            shades[other] = tile_shade(model, other, vertices, faces)
    around = [(tile[0] + di, tile[1] + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1)]
    for here in [t for t in around if t in present and t in shades]:
        shade = shades[here]
        normals = np.zeros_like(shade.sums)  # zero: Blender's own normal
        beside = [shades[t] for t in ((here[0] + di, here[1] + dj) for di in (-1, 0, 1) for dj in (-1, 0, 1))
                  if t != here and t in shades and t in present]
        for key, index in shade.borders.items():
            total = shade.sums[index] + sum(other.sums[other.borders[key]] for other in beside if key in other.borders)
            normals[index] = total / max(np.linalg.norm(total), 1e-300)
        present[here].data.normals_split_custom_set_from_vertices(normals.astype(np.float32))


def forget() -> None:
    """Another file opens: its worlds' tiles are shaded afresh."""
    SHADES.clear()


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
