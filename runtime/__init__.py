"""The sinshape runtime: sample shapes from a trained .onnx model, no torch.

    from sinshape import runtime

    model = runtime.load_model("towerruins.onnx")    # once: checks and prepares the file
    triplane = runtime.sample(model, seed=3)          # a new shape (seed None: the training shape)
    request = runtime.SampleRequest(3, size=(2, 1, 1), scale=4, grow=(1.5, 1, 1))  # what every front end asks
    triplane = runtime.make(model, request)           # ... made: a plain sample, or its one edit
    edited = runtime.compose(model, 7, [runtime.Part(3, (0, 0, 0), (30, 36, 31))])  # that box of seed 3 in seed 7
    mesh = runtime.extract(model, triplane, scale=4)  # trimesh.Trimesh, in the input mesh's frame
    grid = runtime.dense(model, triplane, scale=1)    # (X, Y, Z) occupancy in [0, 1]
    runtime.sample_many("towerruins.onnx", range(1000), "out/{seed}.glb")  # a resumable job on all cores
    data, info = runtime.asset_bytes(model, request, runtime.AssetOptions((20000, 5000, 1200), 2048))  # a game asset

Stages, one module each: load -> generate -> query -> mesh -> write; edit
composes a sample from boxes of others; request is the one sample request
(its checks, and `make`, which picks the plain sample or its edit); many
runs requests for many seeds on worker processes or a Ray cluster; asset
packs a request as a game asset (.glb: levels of detail, UVs, maps baked by
bake, written by gltf; the assets extra).

Sampling imports numpy, onnxruntime and threadpoolctl, and trimesh only
for a whole mesh in memory (a .ply streams without it); render adds pillow.
It reads ONNX itself (onnxfile), format 1 and 2 files included, and never
imports the onnx package, nor torch. It stands on sinshape.core (errors,
the memory budget, the model format, the noise, atomic files) and on
sinshape.prep where it reads an example as training does: render draws a
mesh file with its colour (prep's mesh reader: trimesh and pillow, no
extra), layout voxelises a rough mesh (prep.voxelize, which needs scipy)
and evaluate scores against the reference grid (prep.pyramid: scipy, h5py,
scikit-image); those two need the prep extra. Never on sinshape.trainer,
.cli or .serve: a model file and its manifest (docs/FORMAT.md) are all it
shares with the trainer. `__version__` is the installed sinshape
distribution's version.
"""

import importlib

# Where each public name lives. They are imported on first use, so that
# importing a light module (for the CLI's --help) does not
# pull in onnxruntime and onnx.
_EXPORTS = {
    "InputError": "sinshape.core.errors", "MemoryLimitError": "sinshape.core.errors", "Model": "load",
    "load_model": "load", "TriPlane": "generate", "sample": "generate", "interpolate": "generate",
    "extract": "mesh", "dense": "query", "points": "query", "colours": "colour", "sample_many": "many", "compose": "edit",
    "Part": "edit", "SampleRequest": "request", "Layout": "request", "make": "request", "AssetOptions": "asset",
    "asset_bytes": "asset",
}
__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name):
    if name == "__version__":  # importlib.metadata costs more than the rest of an import
        from importlib import metadata

        return metadata.version("sinshape")
    if name in _EXPORTS:
        module = _EXPORTS[name]
        return getattr(importlib.import_module(module if "." in module else f".{module}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
