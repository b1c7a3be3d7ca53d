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


@pytest.mark.parametrize("units", [32, 5])  # the shipped models' width; one that needs padding to 4
def test_the_kernel_decodes_live_voxels_as_the_decoder_does(build, units):
    rng = np.random.default_rng(units)
    x, y, z, stride = 3, 4, 5, -(-units // 4) * 4
    terms = [rng.normal(size=(h, w, units)).astype(np.float32) for h, w in ((x, y), (x, z), (y, z))]
    bias, w2 = rng.normal(size=units).astype(np.float32), rng.normal(size=units).astype(np.float32)
    live = rng.random((x, y, z)) < 0.5
    padded = [np.pad(a.reshape(-1, units), ((0, 0), (0, stride - units))) for a in terms]
    padded += [np.pad(bias, (0, stride - units)), np.pad(w2, (0, stride - units))]
    blobs = [a.astype(np.float32).tobytes() for a in padded] + [live.astype(np.uint8).tobytes()]
    offsets = np.cumsum([0] + [len(b) for b in blobs]).tolist()  # each a multiple of 4 but the last
    out = offsets[-1] + (-offsets[-1]) % 4

    store = wasmtime.Store()
    memory = wasmtime.Memory(store, wasmtime.MemoryType(wasmtime.Limits(1, None)))
    decode = wasmtime.Instance(store, wasmtime.Module(store.engine, shipped_bytes(build)), [memory]).exports(store)["decode"]
    for blob, at in zip(blobs, offsets):
        memory.write(store, blob, at)
    sentinel = np.full(x * y * z, 7.0, np.float32).tobytes()

    pre = terms[0][:, :, None] + terms[1][:, None] + terms[2][None] + bias  # (x, y, z, units)
    expected = (np.maximum(pre, 0) @ w2).ravel()
    for everywhere in (0, 1):
        memory.write(store, sentinel, out)
        decode(store, *offsets[:6], everywhere, out, x, y, z, stride)
        got = np.frombuffer(memory.read(store, out, out + x * y * z * 4), np.float32)
        decoded = np.ones(x * y * z, bool) if everywhere else live.ravel()
        np.testing.assert_allclose(got[decoded], expected[decoded], rtol=1e-5, atol=1e-5)
        assert (got[~decoded] == 7.0).all()  # the rest untouched
