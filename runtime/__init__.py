"""The sinshape runtime: sample shapes from a trained .onnx model, no torch.

    from sinshape import runtime

    model = runtime.load_model("towerruins.onnx")    # once: checks and prepares the file
    triplane = runtime.sample(model, seed=3)          # a new shape (seed None: the training shape)
    mesh = runtime.extract(model, triplane, scale=4)  # trimesh.Trimesh, in the input mesh's frame
    grid = runtime.dense(model, triplane, scale=1)    # (X, Y, Z) occupancy in [0, 1]

Stages, one module each: load -> generate -> query -> mesh -> write.
"""

from .errors import InputError
from .generate import TriPlane, interpolate, sample
from .load import Model, load_model
from .mesh import extract
from .query import dense, points

__all__ = ["InputError", "Model", "TriPlane", "dense", "extract", "interpolate", "load_model", "points", "sample"]
