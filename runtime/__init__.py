"""The sinshape runtime: sample shapes from a trained .onnx model, no torch.

    from sinshape import runtime

    model = runtime.load_model("towerruins.onnx")    # once: checks and prepares the file
    triplane = runtime.sample(model, seed=3)          # a new shape (seed None: the training shape)
    mesh = runtime.extract(model, triplane, scale=4)  # trimesh.Trimesh, in the input mesh's frame
    grid = runtime.dense(model, triplane, scale=1)    # (X, Y, Z) occupancy in [0, 1]

Stages, one module each: load -> generate -> query -> mesh -> write.
"""

import importlib

# Where each public name lives. They are imported on first use, so that
# importing a light module (runtime.errors, for the CLI's --help) does not
# pull in onnxruntime, trimesh and scikit-image.
_EXPORTS = {
    "InputError": "errors", "MemoryLimitError": "errors", "Model": "load", "load_model": "load", "TriPlane": "generate",
    "sample": "generate", "interpolate": "generate", "extract": "mesh", "dense": "query", "points": "query",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
