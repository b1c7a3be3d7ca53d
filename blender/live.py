"""A sinshape object kept live: its settings -> a runtime request -> its mesh.

Everything here gathers values from Blender data and hands them to the
conversions (convert) and the runtime (request.make, mesh.extract,
many's worker processes); it re-implements none of the runtime. Work on
the main thread is what must touch Blender data or is quick (the model's
check and load, the request); the sample itself goes to work.WORKER.
"""

import contextlib
import dataclasses
import sys
import types
from pathlib import Path

import bpy
import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import check_readable
from sinshape.runtime import asset, layout, load, many_index, many_workers, mesh, write
from sinshape.runtime import request as requests
from sinshape.runtime.load import default_threads

from . import convert, work

MODELS = {}  # (path, SHA-256) -> a loaded model, the few last used
DIGESTS = {}  # (path, size, mtime) -> SHA-256: a file is hashed again only when it changed
KEEP_MODELS = 4
SUSPENDED = []  # non-empty while settings are filled in by the add-on itself: no regeneration
MAX_PART_TEXT = 256  # a kept part's text as the add-on writes it (convert.kept_part) is under 150 characters
MADE = {}  # object name -> what its mesh was made from, (model setting, request) (a world: its tiles' asking)
IN_EDIT_MODE = set()  # names of objects whose regeneration waits for them to leave edit mode


def model_file(reference: str, recorded: str = "") -> tuple:
    """(path, SHA-256) of the model a setting names ('//' relative to the
    .blend), checked: a file is there and is the one `recorded`
    (convert.check_unchanged), a shipped model too; hashed again only when
    it changed."""
    if reference.startswith("//"):
        reference = bpy.path.abspath(reference)
    path = check_readable(convert.model_path(reference), "model file")
    stat = path.stat()
    key = (str(path), stat.st_size, stat.st_mtime_ns)
    if key not in DIGESTS:
        digest = many_index.file_digest(path)
        if digest is None:
            raise InputError(f"{path}: cannot read the model file")
        DIGESTS[key] = digest[1]
    convert.check_unchanged(reference, path, DIGESTS[key], recorded)
    return path, DIGESTS[key]


def load_file(reference: str, recorded: str = "") -> tuple:
    """(the loaded model, its file's SHA-256): loaded once, kept while the file is unchanged."""
    path, digest = model_file(reference, recorded)
    key = (str(path), digest)
    if key not in MODELS:
        if len(MODELS) >= KEEP_MODELS:
            MODELS.pop(next(iter(MODELS)))
        MODELS[key] = load.load_model(path)
    return MODELS[key], digest


def load_model(settings):
    """The model an object's settings name; a file's SHA-256 is recorded the first time."""
    return load_settings(settings)[0]


def load_settings(settings) -> tuple:
    """(the model, its file's SHA-256) that settings (a sample's or a
    world's) name; the SHA-256 is recorded the first time (a shipped
    model's too: an update of the extension may replace it)."""
    model, digest = load_file(settings.model, settings.model_sha256)
    if not settings.model_sha256:
        with suspended():
            settings.model_sha256 = digest
    return model, digest


def model_factors(settings, up: str) -> tuple:
    return convert.factors_to_model(tuple(settings.size), up)


def points_between(points, source, target) -> np.ndarray:
    """(n, 3) points in object `source`'s space -> object `target`'s."""
    matrix = np.array(target.matrix_world.inverted() @ source.matrix_world)
    return np.asarray(points, float) @ matrix[:3, :3].T + matrix[:3, 3]


def keep_part(obj, model) -> str:
    """The kept part's text: from the box object where there is one (its
    bounds, in the sample's space), else as recorded."""
    settings = obj.sinshape
    box = settings.keep_box
    if box is None:
        if not settings.keep_part:
            raise InputError("choose a box object to `keep` (Add Keep Box)", "keep")
        if len(settings.keep_part) > MAX_PART_TEXT:  # the runtime would echo all of it
            raise InputError(f"the kept part recorded on the object is {len(settings.keep_part)} characters, not a "
                             "part's SEED:X0,Y0,Z0:X1,Y1,Z1: choose a box object to `keep` (Add Keep Box)", "keep")
        return settings.keep_part
    corners = points_between([tuple(corner) for corner in box.bound_box], box, obj)
    up = model.manifest.up
    return convert.kept_part(settings.keep_seed, corners, up, model.manifest, model_factors(settings, up))


def request_of(obj, model) -> requests.SampleRequest:
    """The request an object's settings stand for (its kept part recorded)."""
    settings = obj.sinshape
    values = dict(convert.table_values(settings, convert.SAMPLE_TABLE_SETTINGS),
                  size=tuple(settings.size), edit=settings.edit, grow=tuple(settings.grow), anchor=tuple(settings.anchor),
                  layout=convert.layout_from_text(settings.layout_shape, settings.layout_bits))
    if settings.edit == "KEEP":
        values["keep"] = keep_part(obj, model)
        if settings.keep_part != values["keep"]:
            with suspended():
                settings.keep_part = values["keep"]
    return convert.sample_request(values, model.manifest.up)


# Bytes a face costs here at its peak: the runtime's mesh, its copy turned
# to Z up, its edges found in numpy, and Blender's own mesh (291 measured
# for terrain at 6x6x6, 2.6 million faces); smoothing costs the runtime more.
BYTES_PER_FACE = 384


def make_mesh(model, request, progress=None) -> tuple:
    """(vertices along Blender's axes, triangles, their edges, a coloured
    model's sRGB colours or None) of the sample a request asks for:
    request.make and mesh.extract (which colours a coloured model's mesh),
    then the turn to Z up. A size or scale whose mesh would not fit in
    memory is refused before any of it is made (request.check_memory, with
    this add-on's own copies counted), and a memory error all the same is
    one line, never a traceback."""
    per_face = max(BYTES_PER_FACE, mesh.held_per_face(request.smooth, largest=request.largest))
    try:
        triplane = requests.make(model, request, per_face=per_face)
        result = mesh.extract(model, triplane, progress=progress, per_face=per_face, **request.mesh_options())
        if not len(result.faces):
            raise InputError("the sample has no surface at this size and scale; the mesh is left as it was")
        return blender_arrays(result.vertices, result.faces, model.manifest.up,
                              convert.byte_colours(result.visual.vertex_colors) if model.manifest.colour else None)
    except MemoryError:
        raise InputError("the sample ran out of memory: choose a smaller size or scale") from None


def blender_arrays(vertices, faces, up: str, colours=None) -> tuple:
    """A sample's mesh in the model's frame (and its colours) -> what set_mesh puts into Blender."""
    faces = np.asarray(faces)
    return convert.to_blender(vertices, up), faces, convert.triangle_edges(faces), colours


COLOUR_MATERIAL = "sinshape colour"


def colour_material():
    """The material that shows a mesh's colour attribute (convert.COLOUR) as
    its base colour: made once per file, shared by every coloured object."""
    material = bpy.data.materials.get(COLOUR_MATERIAL)
    if material is None:
        material = bpy.data.materials.new(COLOUR_MATERIAL)
        if material.node_tree is None:  # Blender before 5.0 makes a material without nodes
            material.use_nodes = True
        nodes = material.node_tree.nodes
        shader = nodes.get("Principled BSDF") or nodes.new("ShaderNodeBsdfPrincipled")
        attribute = nodes.new("ShaderNodeAttribute")
        attribute.attribute_name = convert.COLOUR
        attribute.location = (shader.location.x - 300, shader.location.y)
        material.node_tree.links.new(attribute.outputs["Color"], shader.inputs["Base Color"])
    return material


def put_mesh(mesh, arrays, smooth_shading: bool) -> None:
    """(vertices, faces, edges, colours) into a bpy Mesh; a coloured one
    wears colour_material, a grey one none of it."""
    vertices, faces, edges, colours = arrays
    convert.fill_mesh(mesh, vertices, faces, smooth_shading, edges, colours)
    material = bpy.data.materials.get(COLOUR_MATERIAL)
    if colours is not None and COLOUR_MATERIAL not in mesh.materials:
        mesh.materials.append(colour_material())
    elif colours is None and material is not None and material.name in mesh.materials:
        mesh.materials.pop(index=mesh.materials.find(material.name))


@contextlib.contextmanager
def suspended():
    """Settings written inside this block regenerate nothing."""
    SUSPENDED.append(True)
    try:
        yield
    finally:
        SUSPENDED.pop()


def set_mesh(obj, arrays, request=None) -> None:
    """Put (vertices, faces, edges, colours) into an object's mesh; the
    request it was made from is remembered. A mesh shared with other
    objects (a linked duplicate, Alt+D) is theirs too: this object gets a
    mesh of its own first."""
    if obj.data.users > 1:
        obj.data = obj.data.copy()
    put_mesh(obj.data, arrays, obj.sinshape.shade_smooth)
    obj.sinshape.error = ""
    MADE[obj.name] = (obj.sinshape.model, request)


def failed(name: str, error: InputError) -> None:
    """An error of work done off the main thread: on the object, and reported."""
    obj = bpy.data.objects.get(name)
    if obj is not None:
        obj.sinshape.error = str(error)
    report_later(f"{name}: {error}")


def report_later(message: str, kind: str = "ERROR") -> None:
    """A report from outside an operator (a property's update, a timer):
    the report operator's, run by a timer; printed in background mode."""
    if bpy.app.background:
        print(f"sinshape: {message}")
        return

    def report():
        bpy.ops.sinshape.report(kind=kind, message=message)

    bpy.app.timers.register(report)


def regenerate(obj, force: bool = False) -> None:
    """Make an object's mesh from its settings: at once in background mode,
    else off the main thread (work.WORKER). What is wrong before the work
    (the model, the request) raises InputError here, and in background mode
    the work's own errors too; each is also recorded on the object. The
    mesh is replaced only by a finished sample. Unless `force`, the model
    and request the mesh was made from make nothing again."""
    settings = obj.sinshape
    try:
        if obj.mode == "EDIT":
            IN_EDIT_MODE.add(obj.name)
            raise InputError(f"{obj.name} is in edit mode: leave it to regenerate the sample")
        IN_EDIT_MODE.discard(obj.name)
        model = load_model(settings)
        request = request_of(obj, model)
        if not force and MADE.get(obj.name) == (settings.model, request):
            return
        name = obj.name
        job = work.Job(name, f"{name} (seed {request.seed})",
                       compute=lambda job: job.deliver(make_mesh(model, request, job.progress)),
                       apply=lambda arrays: apply_to(name, arrays, request),
                       fail=lambda error: failed(name, error))
        work.WORKER.submit(job)
    except InputError as error:
        settings.error = str(error)
        raise


def apply_to(name: str, arrays, request) -> None:
    obj = bpy.data.objects.get(name)
    if obj is None or not obj.sinshape.active:
        return
    if obj.mode == "EDIT":  # entered while the work ran: made again when it is left
        IN_EDIT_MODE.add(name)
        return
    set_mesh(obj, arrays, request)


def left_edit_mode() -> None:
    """After a change in the scene: samples whose regeneration was refused
    in edit mode and that have left it are made now (their error goes)."""
    for name in list(IN_EDIT_MODE):
        obj = bpy.data.objects.get(name)
        if obj is None or not obj.sinshape.active:
            IN_EDIT_MODE.discard(name)
        elif obj.mode != "EDIT":
            try:
                regenerate(obj)
            except InputError as error:
                report_later(f"{name}: {error}")


def changed(settings, context) -> None:
    """A setting's update: regenerate its object; an error goes on the object and in a report."""
    if SUSPENDED or not settings.active:
        return
    obj = settings.id_data
    try:
        regenerate(obj)
    except InputError as error:
        report_later(f"{obj.name}: {error}")


def new_object(collection, name: str, arrays, settings: dict, request=None):
    """A new sample object in `collection`, its settings filled in."""
    obj = bpy.data.objects.new(name, bpy.data.meshes.new(name))
    with suspended():
        for key, value in settings.items():
            setattr(obj.sinshape, key, value)
        obj.sinshape.active = True
    set_mesh(obj, arrays, request)
    collection.objects.link(obj)
    return obj


def settings_values(settings) -> dict:
    """An object's settings as a dict (to copy them onto another object)."""
    names = [p.identifier for p in settings.bl_rna.properties if p.identifier not in ("rna_type", "name")]
    return {name: getattr(settings, name) for name in names}


def variation_pool(model_path: Path, request, count: int):
    """many's workers for `count` seeds of `request`: processes on every
    core (each loads the model once), or this process where one would do."""
    workers = min(default_threads(), count)
    threads = max(1, default_threads() // workers)
    if workers == 1:
        return many_workers.InProcess(model_path, ".ply", threads, request)
    with plain_main():
        return many_workers.Processes(model_path, ".ply", threads, request, "seed", workers)


@contextlib.contextmanager
def plain_main():
    """Worker processes started inside this block do not run the program
    that started this Python again (multiprocessing's spawn re-imports
    __main__ in each): in them bpy cannot be imported, so a script that
    imports it (`blender --python`, a benchmark) would end each worker as
    it starts, and the pool would start another, for ever."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


def variations(context, obj, seeds, arrange: str, collection_name: str) -> None:
    """One new sample object per seed, with `obj`'s settings (its edit
    too), in a new collection: in a grid beside `obj` (arrange 'GRID') or
    where it is ('PLACE'). Made by many's worker processes; each object
    appears as its seed is done."""
    settings = obj.sinshape
    model = load_model(settings)
    request = request_of(obj, model)
    base = settings_values(settings)
    base.update(keep_box=None, layout_object=None)
    up = model.manifest.up
    collection = bpy.data.collections.new(collection_name)
    context.scene.collection.children.link(collection)
    seeds = list(seeds)
    columns = max(1, int(np.ceil(np.sqrt(len(seeds)))))
    step = np.array(obj.dimensions) * 1.25
    origin = obj.matrix_world.copy()
    name = obj.name

    def compute(job):
        pool = variation_pool(model.path, dataclasses.replace(request, seed=None), len(seeds))
        try:
            pending = list(seeds)
            running = 0
            for done in range(len(seeds)):
                while pending and running < pool.slots:
                    pool.submit(pending.pop(0))
                    running += 1
                data, record = pool.next_result()
                running -= 1
                points, faces, colours = convert.ply_arrays(data)
                job.deliver((record["seed"], blender_arrays(points, faces, up, colours)))
                job.progress(done + 1, len(seeds))
        finally:
            pool.close()

    def apply(result):
        seed, arrays = result
        index = seeds.index(seed)
        made = new_object(collection, f"{name} seed {seed}", arrays, {**base, "seed": seed},
                          request.with_seed(seed))
        made.matrix_world = origin
        if arrange == "GRID":
            row, column = divmod(index + 1, columns)
            made.location = np.array(origin.translation) + np.array([column * step[0], -row * step[1], 0.0])

    work.WORKER.submit(work.Job(f"{name} variations", f"{len(seeds)} variations of {name}", compute, apply,
                                lambda error: failed(name, error)))


def show_layout(obj):
    """The coarse layout of an object's sample as a cube object (its
    applied layout, or its seed's own), placed over the sample."""
    settings = obj.sinshape
    model = load_model(settings)
    up = model.manifest.up
    factors = model_factors(settings, up)
    applied = convert.layout_from_text(settings.layout_shape, settings.layout_bits)
    if applied is not None and applied.shape == layout.cells(model.manifest, factors)[2]:
        grid = applied.grid()
    else:
        grid = layout.layout(model, settings.seed, 0, factors)
    vertices, quads = convert.layout_cubes(grid, model.manifest, factors)
    name = f"{obj.name} layout"
    cubes = settings.layout_object
    if cubes is None or cubes.type != "MESH":
        cubes = bpy.data.objects.new(name, bpy.data.meshes.new(name))
        for collection in obj.users_collection:
            collection.objects.link(cubes)
        with suspended():
            settings.layout_object = cubes
    convert.fill_mesh(cubes.data, convert.to_blender(vertices, up), quads)
    cubes.matrix_world = obj.matrix_world.copy()
    cubes.hide_set(False)
    return cubes


def apply_layout(obj) -> None:
    """Read the layout's cubes back to a grid and make the sample from it."""
    settings = obj.sinshape
    cubes = settings.layout_object
    if cubes is None or cubes.type != "MESH":
        raise InputError("show the layout first: its cubes are what is applied", "layout")
    if cubes.mode == "EDIT":
        cubes.update_from_editmode()
    model = load_model(settings)
    up = model.manifest.up
    vertices = convert.to_model(points_between(convert.mesh_vertices(cubes.data), cubes, obj), up)
    grid = convert.cubes_layout(vertices, *convert.mesh_faces(cubes.data), model.manifest, model_factors(settings, up))
    if not grid.any():
        raise InputError("the layout's cubes lie outside the sample: nothing to apply", "layout")
    shape, text = convert.layout_text(grid)
    with suspended():
        settings.layout_shape, settings.layout_bits, settings.edit = shape, text, "LAYOUT"
    regenerate(obj, force=True)


def export_asset(obj, path: Path, add_objects: bool, values: dict) -> list:
    """Write the sample of `obj` as a game asset (runtime.asset) to `path`,
    and with add_objects import it with Blender's glTF importer, placed as
    the sample is (its levels' frame is the sample's mesh's: glTF's Y up is
    turned to Blender's Z as the sample's model frame is). The importer
    puts the coarser levels, outside the file's scene, in a collection it
    excludes from the view layer (Orphan Nodes). `values`: the asset's
    options by ASSET_OPTIONS' names (asset.options_of). Returns the new objects."""
    options = asset.options_of(**values)  # refused before any work
    unread = [name for name in ("compress", "ktx2") if add_objects and getattr(options, name)]
    if unread:  # Blender 5.0's importer refuses EXT_meshopt_compression and KHR_texture_basisu (tested)
        raise InputError(f"Blender's glTF importer cannot read an asset made with {' or '.join(unread)}: "
                         "untick Add to scene to write it alone", unread[0])
    try:
        import meshoptimizer  # noqa: F401
        import xatlas  # noqa: F401
    except ImportError:
        raise InputError("a game asset needs meshoptimizer and xatlas, which this Blender's Python lacks: "
                         "pip install 'sinshape[assets]' into it") from None
    model = load_model(obj.sinshape)
    write.write_request(model, request_of(obj, model), path, asset=options)
    if not add_objects:
        return []
    before = set(bpy.data.objects)
    bpy.ops.import_scene.gltf(filepath=str(path))
    added = [other for other in bpy.data.objects if other not in before]
    for other in added:
        if other.parent is None:
            placed = other.matrix_world.copy()
            placed.translation = (0.0, 0.0, 0.0)  # the file stands on its base at the origin; here it overlays the sample
            other.matrix_world = obj.matrix_world @ placed
        if other.name in bpy.context.view_layer.objects:  # not the coarser levels, in an excluded collection
            other.select_set(False)
    obj.select_set(True)  # the sample stays the active object, as before the export
    bpy.context.view_layer.objects.active = obj
    return added


def check_models() -> None:
    """After a file opens: each sample's model is there and unchanged, or its error says why."""
    for obj in bpy.data.objects:
        if obj.sinshape.active:
            try:
                model_file(obj.sinshape.model, obj.sinshape.model_sha256)
            except InputError as error:
                obj.sinshape.error = str(error)
                report_later(f"{obj.name}: {error}", "WARNING")


def forget() -> None:
    """Another file opens: its objects were made by no request of this session."""
    work.WORKER.clear()
    MADE.clear()
    IN_EDIT_MODE.clear()
