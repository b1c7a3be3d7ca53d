"""Shared fixtures: tiny inputs and one tiny trained model per test session.

Tests need nothing outside the checkout: inputs are made here, by
trainer/shapes.py, or read from tests/data (see its README for licences).
"""

import h5py
import numpy as np
import pytest


def write_pyramid(path, sizes):
    """An SSG-format .h5 pyramid of a wavy terrain, one grid per size (coarsest first)."""
    with h5py.File(path, "w") as f:
        f.attrs["n_scales"] = len(sizes)
        for i, size in enumerate(sizes):
            x, y, z = np.meshgrid(*[np.linspace(-1, 1, n) for n in size], indexing="ij")
            f.create_dataset(f"scale{i}", data=z < 0.4 * np.sin(3 * x) * np.cos(2 * y))
    return path


@pytest.fixture(scope="session")
def tiny_pyramid(tmp_path_factory):
    return write_pyramid(tmp_path_factory.mktemp("data") / "terrain.h5", [(15, 15, 15), (20, 18, 15)])


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory, tiny_pyramid):
    """A two-level model trained for a few iterations, and its trainer's generator."""
    pytest.importorskip("torch")
    from sinshape.trainer import train
    from sinshape.trainer.config import make_config

    out = tmp_path_factory.mktemp("model") / "tiny.onnx"
    train.train(tiny_pyramid, out, make_config("tiny", iters=3))
    return out
