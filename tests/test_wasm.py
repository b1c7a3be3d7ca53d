"""The browser runtime's WebAssembly kernel (serve/static/sinshape/decode.wat):
the committed module is its source's, and it computes the decoder's hidden
layer as the decoder does, run here in wasmtime on the same bytes the page loads."""

import base64
import importlib.util
import re
from pathlib import Path

import numpy as np
import pytest

wasmtime = pytest.importorskip("wasmtime", reason="the test extra installs wasmtime")

BUILD = Path(__file__).resolve().parents[1] / "tools" / "build_wasm.py"


@pytest.fixture(scope="module")
def build():
    spec = importlib.util.spec_from_file_location("build_wasm", BUILD)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_module_is_built_from_its_source(build):
    assert build.TARGET.read_text() == build.module_js(build.SOURCE.read_text()), "run tools/build_wasm.py"


def shipped_bytes(build) -> bytes:
    return base64.b64decode(re.search(r"'([A-Za-z0-9+/=]+)'", build.TARGET.read_text()).group(1))


class Kernels:
    """The shipped module in wasmtime, on random terms of an (x, y, z) grid with `units` hidden units."""

    def __init__(self, build, units: int, x=3, y=4, z=5):
        rng = np.random.default_rng(units)
        self.shape, self.units, self.stride = (x, y, z), units, -(-units // 4) * 4
        self.terms = [rng.normal(size=(h, w, units)).astype(np.float32) for h, w in ((x, y), (x, z), (y, z))]
        self.bias, self.w2 = rng.normal(size=units).astype(np.float32), rng.normal(size=units).astype(np.float32)
        self.store = wasmtime.Store()
        self.memory = wasmtime.Memory(self.store, wasmtime.MemoryType(wasmtime.Limits(1, None)))
        module = wasmtime.Module(self.store.engine, shipped_bytes(build))
        self.exports = wasmtime.Instance(self.store, module, [self.memory]).exports(self.store)
        self.free = 0
        self.at = [self.put(np.pad(a, ((0, 0), (0, 0), (0, self.stride - units)))) for a in self.terms]
        self.at += [self.put(np.pad(v, (0, self.stride - units))) for v in (self.bias, self.w2)]

    def put(self, array: np.ndarray) -> int:
        """Copy an array into the memory (4-byte aligned): its offset."""
        at, data = self.free, np.ascontiguousarray(array).tobytes()
        self.memory.write(self.store, data, at)
        self.free += len(data) + (-len(data)) % 4
        return at

    def get(self, at: int, count: int) -> np.ndarray:
        return np.frombuffer(self.memory.read(self.store, at, at + count * 4), np.float32)

    def pre(self) -> np.ndarray:
        xy, xz, yz = self.terms
        return xy[:, :, None] + xz[:, None] + yz[None] + self.bias  # (x, y, z, units)


@pytest.mark.parametrize("units", [32, 5])  # the shipped models' width; one that needs padding to 4
def test_the_kernel_decodes_live_voxels_as_the_decoder_does(build, units):
    kernels = Kernels(build, units)
    voxels = int(np.prod(kernels.shape))
    live = np.random.default_rng(1).random(kernels.shape) < 0.5
    at_live = kernels.put(live.astype(np.uint8))
    out = kernels.put(np.zeros(voxels, np.float32))
    expected = (np.maximum(kernels.pre(), 0) @ kernels.w2).ravel()
    for everywhere in (0, 1):
        kernels.memory.write(kernels.store, np.full(voxels, 7.0, np.float32).tobytes(), out)
        kernels.exports["decode"](kernels.store, *kernels.at, at_live, everywhere, out, *kernels.shape, kernels.stride)
        got = kernels.get(out, voxels)
        decoded = np.ones(voxels, bool) if everywhere else live.ravel()
        np.testing.assert_allclose(got[decoded], expected[decoded], rtol=1e-5, atol=1e-5)
        assert (got[~decoded] == 7.0).all()  # the rest untouched


@pytest.mark.parametrize("units", [32, 5])
def test_the_kernel_backward_is_the_decoders_gradient(build, units):
    """backward adds g * w2 * (pre > 0) into each plane's term gradient, summed over the
    voxels that read it: layout.py's d_pre summed along the axis each plane drops."""
    kernels = Kernels(build, units)
    g = np.random.default_rng(2).normal(size=kernels.shape).astype(np.float32)
    g[np.random.default_rng(3).random(kernels.shape) < 0.3] = 0  # voxels that move nothing
    at_g = kernels.put(g)
    (x, y, z), stride = kernels.shape, kernels.stride
    grads = [kernels.put(np.full((h, w, stride), 0.5, np.float32)) for h, w in ((x, y), (x, z), (y, z))]
    kernels.exports["backward"](kernels.store, *kernels.at, at_g, *grads, x, y, z, stride)
    d_pre = g[..., None] * kernels.w2 * (kernels.pre() > 0)
    for at, expected, (h, w) in zip(grads, [d_pre.sum(axis=2), d_pre.sum(axis=1), d_pre.sum(axis=0)],
                                    ((x, y), (x, z), (y, z))):
        got = kernels.get(at, h * w * stride).reshape(h, w, stride)
        np.testing.assert_allclose(got[..., :units], 0.5 + expected, rtol=1e-5, atol=1e-5)  # added to what was there
        assert (got[..., units:] == 0.5).all()  # padding: zero weights add nothing
