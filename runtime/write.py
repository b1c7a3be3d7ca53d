"""Write samples by file extension, never leaving a half-written file.

Meshes: .ply (binary, written here, streamed slab by slab so that its size
is bounded by the disk, not the memory) and .obj .stl .off .glb (trimesh's
exporters, which need the whole mesh in memory). Occupancy grids: .npz.
A coloured model's meshes carry vertex colours: 8-bit sRGB in .ply (uchar
red, green, blue) and .obj (`v x y z r g b`), linear in .glb's COLOR_0, as
glTF says; .stl and .off have none. Its .npz grids carry a colour grid.
Every file goes through core.files.atomic_write, so a crash or Ctrl-C leaves
either the old file or the new one; mesh_bytes and grid_bytes give the same
bytes in memory, to send elsewhere. The encoders of what a request asks for
are here too: sample_bytes (a sample), tile_bytes (a tile of a world) and
request_bytes, which picks between them and a game asset (asset.py).
"""

import io
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError
from sinshape.core.files import GRID_FORMATS, MESH_FORMATS, atomic_write, check_writable
from sinshape.core.manifest import srgb_to_linear

from . import mesh, world, world_tiles
from .asset import asset_bytes
from .colour import dense_grids, matching
from .generate import interpolate
from .mesh import held_per_face
from .request import make


def output_kind(path) -> str:
    """'mesh' or 'grid', from the extension; InputError for anything else."""
    suffix = Path(path).suffix.lower()
    if suffix in MESH_FORMATS:
        return "mesh"
    if suffix in GRID_FORMATS:
        return "grid"
    known = ", ".join([*MESH_FORMATS, *GRID_FORMATS])
    raise InputError(f"{path}: unsupported output format {suffix or '(no extension)'!r}; use one of {known}")



# A binary PLY face: the vertex count (3) and three int32 indices.
PLY_FACE = np.dtype([("count", "u1"), ("indices", "<i4", (3,))])
PLY_COUNT_DIGITS = 10  # counts are zero-padded to a fixed width, so the header can be patched in place


def ply_header(vertices: int, faces: int, colour: bool = False, normals: bool = False) -> bytes:
    return (f"ply\nformat binary_little_endian 1.0\ncomment made by sinshape\n"
            f"element vertex {vertices:0{PLY_COUNT_DIGITS}d}\n"
            "property float x\nproperty float y\nproperty float z\n"
            + "property float nx\nproperty float ny\nproperty float nz\n" * normals
            + "property uchar red\nproperty uchar green\nproperty uchar blue\n" * colour +
            f"element face {faces:0{PLY_COUNT_DIGITS}d}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()


def ply_vertices(vertices: np.ndarray, colours: np.ndarray | None = None, normals: np.ndarray | None = None) -> bytes:
    """Vertices as PLY's binary records: float32 positions, with normals
    ((n, 3)) their float32 nx, ny, nz, and with colours ((n, 3) or (n, 4)
    uint8) their red, green and blue."""
    if colours is None and normals is None:
        return np.asarray(vertices, "<f4").tobytes()  # float32, as trimesh writes PLY
    fields = [("position", "<f4", (3,))] + [("normal", "<f4", (3,))] * (normals is not None) \
        + [("colour", "u1", (3,))] * (colours is not None)
    records = np.empty(len(vertices), np.dtype(fields))
    records["position"] = vertices
    if normals is not None:
        records["normal"] = normals
    if colours is not None:
        records["colour"] = np.asarray(colours)[:, :3]
    return records.tobytes()


def ply_faces(faces: np.ndarray) -> bytes:
    if len(faces) and faces.max() >= 2**31:
        raise InputError("the mesh has more than 2**31 vertices, beyond what a PLY face index holds")
    records = np.empty(len(faces), PLY_FACE)
    records["count"] = 3
    records["indices"] = faces
    return records.tobytes()


def write_ply_pieces(file, pieces, folder, colour: bool = False) -> tuple:
    """Write (vertices, faces) pieces (mesh.pieces: new vertices, global face
    indices) to a binary file as one PLY, holding one piece at a time; with
    `colour`, (vertices, faces, colours) pieces (uint8 sRGB per vertex).
    folder: where the temporary faces go (None: the system's).

    PLY puts all vertices before all faces, so faces wait in an unnamed
    temporary file in `folder` (gone with the process, whatever happens),
    and are appended at the end; then the header's counts are patched.
    Returns (vertices, faces) counts.
    """
    counts = [0, 0]
    file.write(ply_header(0, 0, colour))
    with tempfile.TemporaryFile(dir=folder) as faces_file:
        for vertices, faces, *colours in pieces:
            file.write(ply_vertices(vertices, *colours))
            faces_file.write(ply_faces(faces))
            counts[0] += len(vertices)
            counts[1] += len(faces)
        faces_file.seek(0)
        shutil.copyfileobj(faces_file, file, 1 << 22)
    file.seek(0)
    file.write(ply_header(*counts, colour))
    file.seek(0, os.SEEK_END)
    return tuple(counts)


# (x, y, z) -> (x, z, -y): a quarter turn about x, z up to glTF's +Y (gltf.Z_UP_TO_Y_UP as a matrix).
Z_UP_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)


def mesh_bytes(mesh, suffix: str, normals: bool = False, up: str = "y") -> bytes:
    """A trimesh mesh as the file bytes of a mesh format ('.ply', '.glb', ...),
    with its vertex colours where it has them (8-bit sRGB, see the top),
    and with `normals` its vertex normals (.ply, .glb, .obj). up: the axis
    of the mesh's frame that points up; glTF's up is +Y, so a .glb of a z-up
    frame turns its node a quarter turn about x (as an asset's), the
    vertices kept as they are."""
    colours = mesh.visual.vertex_colors if mesh.visual.kind == "vertex" else None
    if suffix.lower() == ".ply":  # the bytes a streamed write (write_ply_pieces) makes of the same mesh
        vertex_normals = mesh.vertex_normals if normals else None
        return (ply_header(len(mesh.vertices), len(mesh.faces), colours is not None, normals)
                + ply_vertices(mesh.vertices, colours, vertex_normals) + ply_faces(mesh.faces))
    kept_normals = mesh.vertex_normals if normals else None
    if colours is not None and suffix.lower() == ".glb":  # glTF's COLOR_0 is linear
        mesh = mesh.copy()
        linear = srgb_to_linear(np.asarray(colours[:, :3], np.float64) / 255)
        mesh.visual.vertex_colors = np.concatenate([np.round(linear * 255), colours[:, 3:]], axis=1).astype(np.uint8)
        if normals:  # new colours clear the cache that held the given normals: trimesh would write none
            mesh.vertex_normals = kept_normals
    extra = {"include_normals": True} if normals and suffix.lower() == ".glb" else {}
    if suffix.lower() == ".glb" and up == "z":
        import trimesh  # what made `mesh`: already imported

        scene = trimesh.Scene()
        scene.add_geometry(mesh, transform=Z_UP_TO_Y_UP)  # one node, turned
        mesh = scene
    data = mesh.export(file_type=MESH_FORMATS[suffix.lower()], **extra)
    return data.encode() if isinstance(data, str) else data



def grid_bytes(occupancy: np.ndarray, **fields) -> bytes:
    """An occupancy grid (and small metadata arrays: a coloured model's
    `colour` grid among them) as compressed .npz bytes."""
    buffer = io.BytesIO()
    np.savez_compressed(buffer, occupancy=occupancy, **{k: np.asarray(v) for k, v in fields.items()})
    return buffer.getvalue()


def write_mesh(mesh, path, up: str = "y") -> None:
    """Export a trimesh mesh in the format its extension names (up: as mesh_bytes)."""
    data = mesh_bytes(mesh, Path(path).suffix, up=up)
    atomic_write(path, lambda f: f.write(data))


def write_sample(model, triplane, path, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
                 largest: bool = False, frame: str = "input", threads: int | None = None,
                 mesh_progress=None, detail: bool = True) -> None:
    """One sample as the file its extension names: a mesh, or the .npz grid.
    A .ply without smoothing or --largest (which need the whole mesh) is
    streamed slab by slab: any size fits in memory. mesh_progress(done,
    total) is called as meshing goes."""
    check_writable(path, [model.path])  # every name `interpolate` writes, not only the first
    path = Path(path)
    if output_kind(path) == "grid" or path.suffix.lower() != ".ply" or smooth or largest:
        data, _ = sample_bytes(model, triplane, path, scale, smooth, smoother, largest, frame, threads,
                               mesh_progress, detail)
        atomic_write(path, lambda f: f.write(data))
        return
    mesh.check_frame(frame)
    # The matching begins first and runs while the first slabs are meshed; then each piece's new vertices are
    # moved by relief and coloured as they come (mesh.paint): the cost is per vertex.
    surface = matching(model, triplane, detail) if mesh.painted(model, scale, detail) else None
    pieces = mesh.pieces(model, triplane, scale, progress=mesh_progress, threads=threads)
    colour = model.manifest.colour
    if mesh.relieved(model, scale, detail):
        pieces = ((surface.result().relief(v), f) for v, f in pieces)
    if colour:
        pieces = ((v, f, mesh.colour_bytes(surface.result()(v, 1 / scale))) for v, f in pieces)
    if frame == "input":
        pieces = ((mesh.in_frame(v, model.manifest), *rest) for v, *rest in pieces)

    def write(file):
        if not write_ply_pieces(file, pieces, path.parent, colour)[1]:
            raise no_surface(path)

    atomic_write(path, write)


def write_request(model, request, path, inputs=(), threads: int | None = None, mesh_progress=None,
                  asset=None) -> str | None:
    """The sample a request.SampleRequest asks for, made by `request.make`
    and written to `path` with `write_sample`, or as a game asset with
    `asset` (an asset.AssetOptions; path a .glb). The path is checked first,
    against the model and `inputs` (a layout's file) too, so that a bad one
    costs no work. Returns what a user should be told of what was made
    differently from what was asked (an asset's levels capped), or None."""
    check_writable(path, [model.path, *inputs])
    if request.tile is not None or asset is not None:
        data, made = request_bytes(model, request, path, threads, mesh_progress, asset)
        atomic_write(path, lambda f: f.write(data))
        return made.get("capped") if asset is not None else None
    write_sample(model, make(model, request, **made_for(path, request)), path, threads=threads,
                 mesh_progress=mesh_progress, **request.mesh_options())


def made_for(path, request, streamed: bool = True) -> dict:
    """What a sample written to `path` is made for, for its memory check
    (request.check_memory): a grid, a .ply streamed slab by slab (unless
    smoothing or the largest part needs the whole mesh; `streamed` False:
    made in memory), or a whole mesh, its faces costing what its format's do."""
    path = Path(path)
    if output_kind(path) == "grid":
        return dict(output="grid")
    if streamed and path.suffix.lower() == ".ply" and not request.smooth and not request.largest:
        return dict(output="stream")
    return dict(output="mesh", per_face=held_per_face(request.smooth, path.suffix, request.largest))


def request_bytes(model, request, name, threads: int | None = None, mesh_progress=None, asset=None) -> tuple:
    """`sample_bytes` of the sample a request asks for: the file `name` names,
    in memory, and its mesh; a tile of a world (tile_bytes) likewise.
    mesh_progress(done, total) as the work goes (a server stops a job there).
    With `asset` (an asset.AssetOptions), the game asset of either as a
    .glb, and in place of the mesh what it holds (asset.asset_bytes)."""
    if asset is not None:
        if Path(name).suffix.lower() != ".glb":
            raise InputError(f"{Path(name).name}: an asset is written as .glb (glTF's binary), not "
                             f"{Path(name).suffix or '(no extension)'}", "lods")
        return asset_bytes(model, request, asset, Path(name).stem, threads, mesh_progress)
    if request.tile is not None:
        return tile_bytes(model, request, name, mesh_progress)
    return sample_bytes(model, make(model, request, **made_for(name, request, streamed=False)), name,
                        threads=threads, mesh_progress=mesh_progress, **request.mesh_options())


def tile_bytes(model, request, name, progress=None) -> tuple:
    """A tile request (request.SampleRequest with `tile`) as the bytes of the
    file `name` names, and its mesh (None for an .npz grid). progress: as
    world_tiles.tile_occupancy's."""
    suffix = Path(name).suffix.lower()
    options = request.world_options()
    if output_kind(name) == "grid":
        grids = world_tiles.tile_occupancy(model, request.sample_seed, request.tile, request.scale,
                                     colour=world.coloured(model, options), options=options, progress=progress)
        grids = dict(zip(("occupancy", "colour"), grids)) if world.coloured(model, options) else {"occupancy": grids}
        tiling = world.world_tiling(model)
        grid = world.tile_grid(model, tiling, request.scale, options)
        return grid_bytes(**grids, tile=request.tile, corner=world_tiles.tile_corner(model, request.tile),
                          scale=request.scale, lod=options.lod, heights=grid.positions[tiling.up]), None
    import trimesh  # half a second to import: a streamed .ply of a sample does without it

    surface = world_tiles.tile_surface(model, request.sample_seed, request.tile, request.scale, options, progress=progress)
    if not len(surface.faces):
        raise no_surface(Path(name))
    vertices = world_tiles.placed(model, request.tile, surface.vertices, request.frame)
    normals = surface.normals if request.frame == "model" else world_tiles.frame_normals(model, surface.normals)
    tile = trimesh.Trimesh(vertices, surface.faces, vertex_normals=normals, process=False)
    if surface.colours is not None:
        tile.visual.vertex_colors = surface.colours
    return mesh_bytes(tile, suffix, normals=True, up=model.manifest.up), tile


def sample_bytes(model, triplane, path, scale: float = 1.0, smooth: int = 0, smoother: str = "laplacian",
                 largest: bool = False, frame: str = "input", threads: int | None = None,
                 mesh_progress=None, detail: bool = True) -> tuple:
    """One sample as the bytes of the file `path` names, made in memory, and
    its mesh (None for a grid): what write_sample writes, for a caller that
    writes elsewhere or wants the mesh too. mesh_progress(done, total) as
    the mesh's slabs are made (once, before a grid)."""
    path = Path(path)
    if output_kind(path) == "grid":
        if mesh_progress:  # nothing done of the grid yet: a server's job given up meanwhile stops here
            mesh_progress(0, 1)
        return grid_bytes(**dense_grids(model, triplane, scale, detail), size=triplane.size, scale=scale), None
    result = mesh.extract(model, triplane, scale, smooth, smoother, largest, frame, progress=mesh_progress,
                          threads=threads, per_face=mesh.held_per_face(smooth, path.suffix, largest), detail=detail)
    if not len(result.faces):
        raise no_surface(path)
    return mesh_bytes(result, path.suffix, up=model.manifest.up), result


def no_surface(path: Path) -> InputError:
    return InputError(f"{path.name}: the sample has no surface at this scale and size; nothing written")


def write_samples(model, outputs, progress=None, **options) -> None:
    """Write each (path, tri-plane) of `outputs` with `write_sample(**options)`,
    then call progress(). `outputs` is consumed lazily, so a generator that
    makes each tri-plane when asked keeps one sample in memory at a time:
    `write_interpolation` is this loop (`sample --seeds` is runtime.many)."""
    for path, triplane in outputs:
        write_sample(model, triplane, path, **options)
        if progress:
            progress()


def write_interpolation(model, request, seed_b: int, alpha, steps: int, path, progress=None) -> None:
    """Write `steps` blends of the request's seed and seed_b
    (`generate.interpolate` at weight alpha(k), as `generate.blend_weights`
    makes it) to path(k), each made when its turn comes, with
    `write_samples`, at the request's size and with its surface options (a
    plain request.SampleRequest: no edit, no tile, no reconstruction). The
    first path is checked before any work."""
    refused = [name for name, given in (("recon", request.recon), ("tile", request.tile is not None)) if given]
    refused += request.edits() + request.world_fields()
    if refused:
        raise InputError(f"a blend of two seeds is a plain sample; it takes no `{refused[0]}`", refused[0])
    first = path(0)
    output_kind(first)
    check_writable(first, [model.path])
    outputs = ((path(k), interpolate(model, request.sample_seed, seed_b, alpha(k), request.size))
               for k in range(steps))
    write_samples(model, outputs, progress, **request.mesh_options())


def write_block(model, request, tiles, path, progress=None) -> None:
    """A block of tiles of the world of `request` (world_tiles.block_mesh) as one
    mesh file, checked before any work."""
    if output_kind(path) != "mesh":
        raise InputError(f"{path}: a block is written as a mesh ({', '.join(MESH_FORMATS)})")
    check_writable(path, [model.path])
    block = world_tiles.block_mesh(model, request, tiles, progress)
    if not len(block.faces):
        raise no_surface(Path(path))
    write_mesh(block, path, model.manifest.up)
