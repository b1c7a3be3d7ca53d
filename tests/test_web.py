"""Sampling in the browser: the JavaScript runtime (serve/static/sinshape/) in
Debian's headless chromium against the Python runtime, on a site written by
`sinrun export-web`, and the switch on the page of `sinrun serve`."""

import base64
import json
import re
from pathlib import Path

import numpy as np
import onnx
import pytest
from click.testing import CliRunner
from onnx import TensorProto, helper

from browser import (CLICKABLE_JS, edits_text, http_server_process, launch, layout_in_page, open_page,
                     site_server_process, wait_cells)
from conftest import TINY_ONNX as TINY, sealed_bytes
from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime import cubes, load, mesh, query
from sinshape.core.errors import InputError
from sinshape.runtime.generate import sample
from sinshape.runtime.request import SampleRequest, make
from sinshape.serve import site
from test_cli_train import assert_one_line_error
from test_request import expected as expected_outcome


VECTORS = json.loads((Path(__file__).parent / "data" / "noise_vectors.json").read_text())
TERRAIN = models.find("terrain")

# Runs in the page: load the model once, sample, query the grid, mesh it.
SAMPLE_JS = """async ([seed, size, scale, name = 'terrain']) => {
  const s = await import('./static/sinshape/runtime.js');
  window.models ??= {};
  window.models[name] ??= await s.loadModel(new Uint8Array(await (await fetch(`models/${name}.onnx`)).arrayBuffer()),
                                            { name: `${name}.onnx` });
  const model = window.models[name];
  const tri = await s.sample(model, seed, size);
  const grid = await s.dense(model, tri, scale);
  const m = s.surface(grid, tri.size);
  const bytes = new Uint8Array(grid.data.buffer);
  let text = '';
  for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
  let volume = 0;
  const p = m.positions, f = m.faces;
  for (let i = 0; i < f.length; i += 3) {
    const [a, b, c] = [3 * f[i], 3 * f[i + 1], 3 * f[i + 2]];
    volume += p[a] * (p[b + 1] * p[c + 2] - p[b + 2] * p[c + 1]) - p[a + 1] * (p[b] * p[c + 2] - p[b + 2] * p[c])
      + p[a + 2] * (p[b] * p[c + 1] - p[b + 1] * p[c]);
  }
  return { grid: btoa(text), shape: grid.shape, size: tri.size, vertices: p.length / 3, faces: f.length / 3,
           volume: volume / 6, backend: model.backend };
}"""


@pytest.fixture(scope="module")
def terrain():
    return load.load_model(TERRAIN, threads=2)


@pytest.fixture(scope="module")
def playwright():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as running:
        yield running


@pytest.fixture(scope="module")
def browser(playwright):
    launched = launch(playwright)
    yield launched
    launched.close()


@pytest.fixture(scope="module")
def site_page(tmp_path_factory, browser):
    """`sinrun export-web terrain -o site && cd site && python serve.py`, in chromium
    (page.answers: the headers of every answer the page and its worker got, by path)."""
    folder = tmp_path_factory.mktemp("web") / "site"
    site.export_site(["terrain", "towerruins"], folder)
    with site_server_process(folder) as base:
        page = open_page(browser, base)
        page.base, page.folder, page.answers = base, folder, {}
        page.on("response", lambda answer: page.answers.setdefault(answer.url.removeprefix(base), answer.headers))
        yield page
        page.close()


def wait_done(page, timeout=60_000) -> str:
    page.wait_for_function("['ready', 'error'].includes(document.body.dataset.state)", timeout=timeout)
    return page.evaluate("document.body.dataset.state")


def test_the_exported_page_samples_in_the_browser(site_page, terrain, tmp_path):
    page = site_page
    page.goto(f"{page.base}/?seed=3&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    status = page.text_content("#status")
    # The terrain carries its example's relief, which the Python runtime adds (docs/WEB.md, "One runtime").
    assert re.fullmatch(r"[\d,]+ faces · \d+\.\d\d s · in this browser · without its relief: sinrun serve makes them",
                        status), status
    python_faces = len(mesh.band_mesh(terrain, sample(terrain, 3), 1).faces)
    assert abs(int(status.split()[0].replace(",", "")) - python_faces) <= python_faces / 1000
    # serve.py sends the isolation headers (WASM on threads) and the .gz copies, which the browser unpacks.
    assert page.evaluate("crossOriginIsolated")
    assert re.search(r"on WASM, \d+ threads?; model loaded", page.text_content("#backend"))
    wasm = page.answers["/static/vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm"]
    assert wasm["content-encoding"] == "gzip" and wasm["content-type"] == "application/wasm"
    assert page.answers["/static/vendor/onnxruntime-web/ort.wasm.min.mjs"]["content-encoding"] == "gzip"
    assert not page.is_visible("#where")  # a static site has no server to switch to
    sides = page.evaluate("() => { const s = []; window.sinshapeView.scene.traverse((n) => n.isMesh && s.push(n.material.side)); return s; }")
    assert sides == [0], sides  # the browser's mesh: front faces only (THREE.FrontSide), as the server's
    shot = page.locator("#view canvas").screenshot(path=tmp_path / "seed3.png")
    assert len(shot) > 20_000, f"the view looks blank: {tmp_path / 'seed3.png'}"
    page.click("#next")
    page.wait_for_function("location.search.includes('seed=4&') && document.body.dataset.state === 'ready'",
                           timeout=30_000)
    assert page.text_content("#status") != status
    assert not page.errors and not page.outside


def test_without_the_isolation_headers_the_page_runs_on_one_thread(site_page):
    """`python -m http.server` sends no COOP/COEP: the page samples on one thread and says why."""
    with http_server_process(site_page.folder) as base:
        page = open_page(site_page.context.browser, base)
        try:
            page.goto(f"{base}/?seed=3&up=z")
            assert wait_done(page) == "ready", page.text_content("#error")
            assert not page.evaluate("crossOriginIsolated")
            assert "WASM, 1 thread (the page is not cross-origin isolated" in page.text_content("#backend")
            assert not page.errors and not page.outside
        finally:
            page.close()


def test_a_browser_sample_shows_progress_and_cancel_ends_its_worker(site_page):
    """The runtime runs in a worker: the page shows how far a long sample is;
    cancel ends the worker, and the next sample starts a fresh one."""
    page = site_page
    page.goto(f"{page.base}/?seed=3&scale=6&up=z")  # seconds of grid and meshing on one thread
    page.wait_for_function("document.getElementById('progress').value > 0", timeout=60_000)
    assert re.fullmatch(r"(querying the grid|meshing)… \d+%", page.text_content("#status")), page.text_content("#status")
    assert page.evaluate("document.body.dataset.state") == "loading" and page.is_visible("#cancel")
    # The runtime's worker; onnxruntime-web's own threads are workers too, started by it.
    runtime_workers = lambda: [w for w in page.workers if w.url.endswith("/static/sinshape/worker.js")]  # noqa: E731
    (worker,) = runtime_workers()
    with worker.expect_event("close"):  # ended, not left to finish
        page.click("#cancel")
    assert page.evaluate("document.body.dataset.state") == "cancelled" and page.text_content("#status") == "cancelled"
    assert not page.is_visible("#cancel") and page.get_attribute("#download", "href") is None
    page.fill("#scale", "1")
    page.press("#scale", "Enter")
    assert wait_done(page) == "ready", page.text_content("#error")
    assert page.text_content("#status").startswith("18,124 faces")  # seed 3 at scale 1, made by a fresh worker
    assert len(runtime_workers()) == 1 and not page.errors and not page.outside


def test_noise_vectors_bit_for_bit(site_page):
    page = site_page
    page.goto(f"{page.base}/README.txt")  # any page of the site, without the viewer
    bits = page.evaluate("""async (vectors) => {
      const { normal } = await import('./static/sinshape/noise.js');
      const hex = (x) => new Uint32Array(Float32Array.of(x).buffer)[0].toString(16).padStart(8, '0');
      return vectors.map((v) => hex(normal(BigInt(v.seed), v.stream, v.position.map(() => 1), v.position)[0]));
    }""", [{**v, "seed": str(v["seed"])} for v in VECTORS])
    assert bits == [v["float32_bits"] for v in VECTORS]
    # Whole blocks too: a 3-D z0 and a tile of a plane stream, bit for bit.
    from sinshape.core import noise

    blocks = page.evaluate("""async () => {
      const { normal } = await import('./static/sinshape/noise.js');
      return [Array.from(normal(42, [0], [5, 4, 3])), Array.from(normal(7, [1, 3, 2, 9], [6, 5], [100, 2000]))];
    }""")
    np.testing.assert_array_equal(np.float32(blocks[0]), noise.z0_noise(42, (5, 4, 3)).ravel())
    np.testing.assert_array_equal(np.float32(blocks[1]), noise.normal(7, (1, 3, 2, 9), (6, 5), (100, 2000)).ravel())


@pytest.mark.parametrize("name, scale, size", [("terrain", 1, (1, 1, 1)), ("terrain", 2, (1, 1, 1)),
                                               ("terrain", 1, (1.5, 1, 0.75)), ("towerruins", 1, (1, 1, 1))])
def test_grid_and_mesh_equal_the_python_runtime(site_page, terrain, name, scale, size):
    page = site_page
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    js = page.evaluate(SAMPLE_JS, [3, list(size), scale, name])
    model = terrain if name == "terrain" else load.load_model(models.find(name), threads=2)
    triplane = sample(model, 3, size)
    expected = query.dense(model, triplane, scale)
    grid = np.frombuffer(base64.b64decode(js["grid"]), np.float32).reshape(js["shape"])
    assert grid.shape == expected.shape and tuple(js["size"]) == triplane.size
    assert np.abs(grid - expected).max() < 1e-4
    assert 0.1 < (expected > 0.5).mean() < 0.9  # a real surface, not an empty or full grid
    # Both runtimes cut the same triangles from the same values: Python's
    # marching cubes on the browser's own grid makes the browser's mesh.
    padded = np.pad(grid, 1)
    side = max(padded.shape) - 1
    cube = np.zeros((side + 1,) * 3, np.float32)
    cube[:padded.shape[0], :padded.shape[1], :padded.shape[2]] = padded
    keys, _, faces = cubes.march(cube, np.zeros((1, 3), int), side)
    assert (len(faces), len(keys)) == (js["faces"], js["vertices"])
    python = mesh.band_mesh(model, triplane, scale)
    assert abs(js["faces"] - len(python.faces)) <= len(python.faces) / 10000  # values differ by < 1e-4
    assert abs(js["vertices"] - len(python.vertices)) <= len(python.vertices) / 10000
    assert js["volume"] == pytest.approx(python.volume, rel=1e-4)  # > 0: faces wound outwards, as Python's


EDIT_JS = """async ([how, args]) => {
  const s = await import('./static/sinshape/runtime.js');
  window.models ??= {};
  window.models.terrain ??= await s.loadModel(new Uint8Array(await (await fetch('models/terrain.onnx')).arrayBuffer()),
                                              { name: 'terrain.onnx' });
  const model = window.models.terrain;
  const tri = await s[how](model, ...args);  // compose, grow or fromLayout
  const grid = await s.dense(model, tri, 1);
  const bytes = new Uint8Array(grid.data.buffer);
  let text = '';
  for (let i = 0; i < bytes.length; i += 8192) text += String.fromCharCode(...bytes.subarray(i, i + 8192));
  return { grid: btoa(text), shape: grid.shape };
}"""


def edited_in_page(page, how, args) -> np.ndarray:
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    js = page.evaluate(EDIT_JS, [how, args])
    return np.frombuffer(base64.b64decode(js["grid"]), np.float32).reshape(js["shape"])


def test_composing_and_growing_equal_the_python_runtime(site_page, terrain):
    """The browser's edit.js against runtime/edit.py: two parts kept, and a sample grown (an anchor of 0.5)."""
    from sinshape.runtime.edit import Part, compose, grow

    parts = [Part(3, (0.0, 0.0, 0.0), (30.0, 25.0, 14.0)), Part(5, (35.0, 10.0, 0.0), (63.0, 40.0, 14.0))]
    cases = [("compose", [7, [{"seed": p.seed, "low": list(p.low), "high": list(p.high)} for p in parts]],
              compose(terrain, 7, parts)),
             ("grow", [3, [1.5, 1, 1], [0.5, 0, 0]], grow(terrain, 3, (1.5, 1, 1), (0.5, 0, 0)))]
    for how, args, triplane in cases:
        grid = edited_in_page(site_page, how, args)
        expected = query.dense(terrain, triplane, 1)
        assert grid.shape == expected.shape and np.abs(grid - expected).max() < 1e-4, how


def test_layouts_equal_the_python_runtime(site_page, terrain):
    """The browser's sinshape/layout.js against runtime/layout.py: a seed's
    layout exactly (also when kept from an earlier call, beside another
    seed's), and the shape of an edited one (a block removed, one
    added): every edited cell as the layout says, the rest close to
    from_layout's, the same on every run."""
    from sinshape.runtime import layout

    page = site_page
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    shown = page.evaluate("""async () => {
      const s = await import('./static/sinshape/runtime.js');
      const model = await s.loadModel(new Uint8Array(await (await fetch('models/terrain.onnx')).arrayBuffer()), { name: 'terrain.onnx' });
      const made = [];  // seed 3's, another seed's, then seed 3's again: kept from the first time
      for (const seed of [3, 4, 3]) made.push(await s.layout(model, seed));
      return made.map(({ grid, shape }) => ({ grid: Array.from(grid), shape }));
    }""")
    base = layout.layout(terrain, 3)
    for seed, made in zip([3, 4, 3], shown):
        np.testing.assert_array_equal(np.array(made["grid"], bool).reshape(made["shape"]), layout.layout(terrain, seed))
    target = base.copy()
    target[10:14, 6:10, 5:] = False  # a tower's top cut off
    target[3, 3, 9] = True
    args = [3, target.ravel().astype(int).tolist(), list(target.shape)]
    grid = edited_in_page(page, "fromLayout", args)
    expected = query.dense(terrain, layout.from_layout(terrain, 3, target))
    # Given the same planes, the fit is Python's to the bit (tests/test_mirror.py); what differs
    # is the generators' and the decoder's float32 (onnxruntime-web's last bits are not
    # onnxruntime's), which the fit's hinge carries to whole voxels: Python's own result with its
    # planes moved by 1e-6 (random signs) before each level's fit crosses 0.5 in 0.0025 to 0.013%
    # of the voxels, by up to 1.6e-2 (measured); the browser's in none, by 3.6e-4. The bound is
    # 8 times the most that moving the planes did.
    crossed = ((grid > 0.5) != (expected > 0.5)).mean()
    print(f"browser vs Python from_layout: max difference {np.abs(grid - expected).max():.2e}, "
          f"{crossed:.4%} of the voxels across 0.5")
    assert crossed < 0.001
    laid = layout.pool(grid, target.shape) > 0.5
    edited = target != base
    assert (laid == target)[edited].all()  # as Python's; the seed's own sample has none of them
    assert (laid != (layout.pool(expected, target.shape) > 0.5)).mean() < 0.01
    np.testing.assert_array_equal(edited_in_page(page, "fromLayout", args), grid)  # deterministic


# Runs in the page: each case of the shared table (its JSON text, whose integers past 2^53 are read
# exactly) made into a request by request.js, in the table's form.
REQUESTS_JS = """async (text) => {
  const { Layout, sampleRequest } = await import('./static/sinshape/request.js');
  const { HeightMap } = await import('./static/sinshape/world.js');
  const exact = (key, value, { source }) => (/^-?\\d+$/.test(source ?? '') && !Number.isSafeInteger(value) ? BigInt(source) : value);
  return JSON.parse(text, exact).map(({ fields }) => {
    try {
      const given = { ...fields };
      if (given.layout?.cells) given.layout = Layout.of(given.layout.cells, given.layout.shape);
      if (given.heights?.values) given.heights = HeightMap.of(given.heights.values, given.heights.shape);
      const made = sampleRequest(given);
      const layout = made.layout && { shape: made.layout.shape, cells: Array.from(made.layout.grid) };
      const heights = made.heights && { shape: made.heights.shape, values: Array.from(made.heights.data) };
      const tile = made.tile && made.tile.map(String);
      return { request: { ...made, seed: made.seed === null ? null : String(made.seed), layout, heights, tile } };
    } catch (error) {
      return { refused: { error: error.constructor.name, fields: error.fields ?? [error.field], message: error.message } };
    }
  });
}"""


def test_requests_are_checked_as_python_checks_them(site_page):
    """request.js against runtime/request.py on the table both meet (tests/data/sample_requests.json):
    the same request from the same fields, the same refusals naming the same fields in the same words."""
    page = site_page
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    text = (Path(__file__).parent / "data" / "sample_requests.json").read_text()
    cases = json.loads(text)
    made = page.evaluate(REQUESTS_JS, text)
    assert len(made) == len(cases) and sum("refused" in case for case in cases) > 30
    for case, got in zip(cases, made):
        expected = expected_outcome(case)
        if "request" in expected and expected["request"]["seed"] is not None:
            expected["request"]["seed"] = str(expected["request"]["seed"])
        if "request" in expected and expected["request"]["tile"] is not None:
            expected["request"]["tile"] = [str(t) for t in expected["request"]["tile"]]
        assert got == expected, case["fields"]


# Runs in the page: the browser's front ends against the table's copy (options.js): what
# request.js refuses, what the worker refuses, what make and each route will not take, and the lists of what the runtime makes, each route is sent and the page sets.
OPTIONS_JS = """async () => {
  const { OPTIONS } = await import('./static/sinshape/options.js');
  const { MAKES, make, sampleRequest } = await import('./static/sinshape/request.js');
  const { ROUTE_TAKES, serverRequest } = await import('./static/viewer/sampling.js');
  const { PAGE_OPTIONS } = await import('./static/viewer/state.js');
  const refusal = async (work) => {
    try { await work(); return null; } catch (error) { return [error.constructor.name, error.message]; }
  };
  const worker = new Worker('./static/sinshape/worker.js', { type: 'module' });
  const answer = await new Promise((resolve) => {
    worker.onmessage = ({ data }) => resolve(data);
    worker.postMessage({ id: 1, type: 'sample', name: 'terrain', request: { seed: 3, colour: 'red' } });
  });
  worker.terminate();
  const tile = { tile: [0, 0], frame: 'tile', smoother: 'taubin' };
  return {
    names: OPTIONS.map((option) => option.name), makes: MAKES, routes: ROUTE_TAKES, page: PAGE_OPTIONS, worker: answer,
    unknown: await refusal(() => sampleRequest({ seed: 3, colour: 'red' })),
    sample: await refusal(() => make(null, sampleRequest({ smoother: 'taubin' }))),
    tile: await refusal(() => make(null, sampleRequest(tile))),
    route: await refusal(() => serverRequest('terrain', sampleRequest(tile), 'glb')),
    sent: serverRequest('terrain', sampleRequest({ seed: 3, smoother: 'taubin', largest: true }), 'glb').url,
  };
}"""


def test_the_page_and_its_worker_are_held_to_the_options_table(site_page):
    """Every option is one the browser runtime makes or refuses when given,
    one each route is sent or refused before sending, one the page sets or
    leaves at its default; a field no option has is refused by request.js and
    by the worker (Python's message), not dropped."""
    from sinshape.runtime.options import EDITS, OPTION, OPTIONS

    page = site_page
    if page.url.rstrip("/").split("?")[0] != page.base:  # the page itself, for its import map
        page.goto(f"{page.base}/?seed=0")
    got = page.evaluate(OPTIONS_JS)
    names = list(OPTION)
    assert got["names"] == names
    for kind in ("sample", "tile"):
        of_kind = {option.name for option in OPTIONS if kind in {"sample" if g in EDITS else g for g in option.goes_with}}
        assert set(got["routes"][kind]) == of_kind, kind
        if kind == "sample":
            assert set(got["makes"]) <= of_kind
    assert set(got["page"]["set"]) | set(got["page"]["left"]) == set(names)
    assert set(got["page"]["set"]).isdisjoint(got["page"]["left"])
    with pytest.raises(InputError) as python:
        SampleRequest.of({"seed": 3, "colour": "red"})
    assert got["unknown"] == ["InputError", str(python.value)]
    assert got["worker"] == {"id": 1, "type": "error", "message": str(python.value), "input": True}
    assert got["sample"] == ["InputError", "the browser runtime makes smoother laplacian only"]
    assert got["tile"] == ["InputError", "the browser runtime makes no tile: a world's tiles come from sinrun serve"]
    assert got["route"] == ["Error", "the tile route cannot take this request's smoother"]
    assert {"seed=3", "smoother=taubin", "largest=true"} <= set(got["sent"].split("?")[1].split("&"))


@pytest.mark.parametrize("text", ["3:0%,0%,0%:50%,100%,100%", "3: 1.5,0,0 :4,2.5,0.75", "+3:0%,0%,0%:100%,100%,100%",
                                  "3:0%,0%,0%:0%,100%,100%", "3:0%,0%,0%:5%,100%,100%", "3:0%,0%,0%:150%,100%,100%",
                                  "x:0,0,0:1,1,1", "3:0,0:1,1,1", "3:a,0,0:1,1,1", "3:0,0,0", "-1:0%,0%,0%:50%,100%,100%",
                                  "3:40%,0%,0%:45%,100%,100%", "3:1,0%,0%:1.5,100%,100%", "3:50%,0,0:20%,1,1"])
def test_parts_are_read_as_python_reads_them(site_page, terrain, text):
    """The page's kept boxes are text, read in the worker by edit.js's parsePart as edit.parse_part
    reads them on the server: the same box in voxels, or the same message."""
    from sinshape.runtime.edit import parse_part
    from sinshape.runtime.generate import scaled_sizes

    page = site_page
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    manifest, size = terrain.manifest, scaled_sizes(terrain.manifest.sizes)[-1]
    got = page.evaluate("""async ([text, manifest, size]) => {
      const { parsePart } = await import('./static/sinshape/edit.js');
      try {
        const { seed, low, high } = parsePart(text, manifest, size);
        return { seed: String(seed), low, high };
      } catch (error) {
        return { message: error.message, field: error.field };
      }
    }""", [text, {"origin": list(manifest.origin), "spacing": list(manifest.spacing)}, list(size)])
    try:
        part = parse_part(text, manifest, size)
    except InputError as error:
        assert got == {"message": str(error), "field": error.parameter}
    else:
        assert got["seed"] == str(part.seed)
        np.testing.assert_allclose([got["low"], got["high"]], [part.low, part.high], rtol=1e-12)


def page_shape_like_python(page, model, triplane) -> dict:
    """The page's shape against the Python runtime's mesh of the same tri-plane (the input's frame)."""
    shown = page.evaluate("window.sinshapeView.shape()")
    made = mesh.extract(model, triplane, 1)
    assert abs(shown["faces"] - len(made.faces)) <= len(made.faces) / 10000, (shown, len(made.faces))
    assert shown["volume"] == pytest.approx(made.volume, rel=1e-4)
    return shown


def wait_for_url(page, *fragments) -> None:
    checks = " && ".join(f"location.search.includes({json.dumps(f)})" for f in fragments)
    page.wait_for_function(f"['ready', 'error'].includes(document.body.dataset.state) && {checks}", timeout=60_000)
    assert page.evaluate("document.body.dataset.state") == "ready", page.text_content("#error")


def test_the_page_keeps_a_box_and_grows_in_the_browser(site_page, terrain):
    """The editor in browser mode: edit.js in the worker makes runtime.edit's shapes;
    the URL replays an edit, undo restores a shape exactly."""
    from sinshape.runtime import edit

    page = site_page
    page.goto(f"{page.base}/?seed=3&up=z&edit=keep&box=0,0,0,60,100,100&other=7")
    assert wait_done(page) == "ready", page.text_content("#error")
    assert page.text_content("#status").endswith("in this browser · without its relief: sinrun serve makes them")
    kept = page_shape_like_python(page, terrain, make(terrain, SampleRequest(7, keep=("3:0%,0%,0%:60%,100%,100%",))))
    page.select_option("#edit", "grow")
    wait_for_url(page, "edit=grow", "grow=2%2C1%2C1")
    for field, value in (("#gx", "1.5"), ("#ax", "0.5")):
        page.fill(field, value)
        page.dispatch_event(field, "change")
    wait_for_url(page, "grow=1.5%2C1%2C1", "anchor=0.5%2C0%2C0")
    page_shape_like_python(page, terrain, edit.grow(terrain, 3, (1.5, 1, 1), (0.5, 0, 0)))
    for _ in range(2):  # the anchor, the factor, then grow itself with the keyboard
        page.click("#undo")
    page.keyboard.press("Control+z")
    wait_for_url(page, "edit=keep", "other=7")
    assert page.evaluate("window.sinshapeView.shape()")["digest"] == kept["digest"]
    assert page.is_disabled("#undo") and not page.is_disabled("#redo")
    # A bad box: the message, before any work.
    page.fill("#bx1", "0")
    page.dispatch_event("#bx1", "change")
    assert wait_done(page) == "error" and "along x it runs from 0% to 0%" in page.text_content("#error")
    assert not page.errors and not page.outside


def test_the_page_edits_a_layout_in_the_browser(site_page, terrain):
    """Blocks in browser mode: the worker makes the seed's layout (runtime.layout's
    grid) and the shape of an edited one, close to from_layout's, the same again on undo and redo."""
    from sinshape.runtime import layout

    page = site_page
    page.goto(f"{page.base}/?seed=3&up=z&edit=layout")
    assert wait_done(page) == "ready", page.text_content("#error")
    base = layout.layout(terrain, 3)
    np.testing.assert_array_equal(layout_in_page(page), base)
    plain = page_shape_like_python(page, terrain, sample(terrain, 3))
    target = page.evaluate(CLICKABLE_JS, [[0, 0, 1], 0])  # a block with its top in view: a click removes it
    page.mouse.click(target["x"], target["y"])
    expected = base.copy()
    expected[tuple(target["cell"])] = False
    wait_cells(page, edits_text(expected, base))
    shown = page.evaluate("window.sinshapeView.shape()")
    made = mesh.extract(terrain, layout.from_layout(terrain, 3, expected), 1)
    print(f"a block removed in the browser: {shown['faces']} faces, volume {shown['volume']:.6g}; "
          f"Python's {len(made.faces)}, {made.volume:.6g}; the seed's own {plain['faces']}, {plain['volume']:.6g}")
    assert shown["digest"] != plain["digest"]
    # measured: 32 faces of 18,192, volume 1.4e-4. The last level's hold leaves cells right
    # at 0.5, where float32 rounding moves the surface: Python's own shape with the planes
    # moved by -1e-6 before each fit is the browser's (volume 44.6667 against 44.6668).
    assert abs(shown["faces"] - len(made.faces)) <= len(made.faces) / 250
    assert shown["volume"] == pytest.approx(made.volume, rel=2e-4)
    assert abs(shown["volume"] - plain["volume"]) > 4 * abs(shown["volume"] - made.volume)  # the fit is there
    page.click("#undo")
    wait_cells(page, "")
    assert page.evaluate("window.sinshapeView.shape()")["digest"] == plain["digest"]
    page.click("#redo")
    wait_cells(page, edits_text(expected, base))
    assert page.evaluate("window.sinshapeView.shape()")["digest"] == shown["digest"]  # the same shape again
    assert not page.errors and not page.outside


def test_smoothing_is_trimeshs_laplacian_filter(site_page, terrain):
    """--smooth in the browser: the filter the Python runtime uses, on the same mesh, to 1e-9."""
    page = site_page
    if not page.url.startswith(page.base):
        page.goto(f"{page.base}/README.txt")
    raw = mesh.band_mesh(terrain, sample(terrain, 3), 1)
    smoothed = page.evaluate("""async ([positions, faces]) => {
      const s = await import('./static/sinshape/runtime.js');
      return Array.from(s.smooth({ positions: Float64Array.from(positions), faces: Uint32Array.from(faces) }, 3).positions);
    }""", [raw.vertices.ravel().tolist(), raw.faces.ravel().tolist()])
    expected = mesh.finish(raw.copy(), smooth=3).vertices
    assert np.abs(np.reshape(smoothed, (-1, 3)) - expected).max() < 1e-9
    assert np.abs(expected - raw.vertices).mean() > 0.01  # it does smooth


def foreign_model(path: Path) -> Path:
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])
    graph = helper.make_graph([helper.make_node("Add", ["x", "x"], ["y"])], "g", [x], [y])
    onnx.save(helper.make_model(graph), path)
    return path


def altered_terrain(path: Path, change, seal=True, source=TERRAIN) -> Path:
    """The terrain model (or `source`) changed, resealed (so that the change itself is what
    is checked), or with its old seal, as an editor that knows nothing of seals leaves it."""
    proto = onnx.load(source)
    change(proto)
    path.write_bytes(sealed_bytes(proto) if seal else proto.SerializeToString())
    return path


def edit_manifest(edit):
    """A change of a model: its manifest edited."""
    def change(proto):
        for prop in proto.metadata_props:
            if prop.key == "sinshape.manifest":
                manifest = json.loads(prop.value)
                edit(manifest)
                prop.value = json.dumps(manifest)
    return change


newer_version = edit_manifest(lambda m: m.update(format_version=99))


def drop_seal(proto):
    kept = [(p.key, p.value) for p in proto.metadata_props if p.key != "sinshape.sha256"]
    del proto.metadata_props[:]
    for key, value in kept:
        proto.metadata_props.add(key=key, value=value)


def flipped_weight(proto):
    tensor = next(t for t in proto.graph.initializer if t.raw_data)
    data = bytearray(tensor.raw_data)
    data[5] ^= 0x10
    tensor.raw_data = bytes(data)


def external_data(proto):
    tensor = proto.graph.initializer[0]
    tensor.data_location = TensorProto.EXTERNAL
    tensor.external_data.add(key="location", value="weights.bin")


def foreign_op(proto):
    proto.graph.node[0].op_type = "Softmax"


def weight_twice(proto):
    """A second, all-zero copy of the last weight: protobuf keeps both, and a reader the last."""
    copy = proto.graph.initializer.add()
    copy.CopyFrom(proto.graph.initializer[len(proto.graph.initializer) - 2])
    copy.raw_data = bytes(len(copy.raw_data))


def sealed_twice(path: Path) -> Path:
    """The terrain model with a second sinshape.manifest entry, sealed (protobuf keeps the last: which is the model's?)."""
    from sinshape.core import manifest as fmt

    proto = onnx.load(TERRAIN)
    drop_seal(proto)
    manifest = next(p.value for p in proto.metadata_props if p.key == "sinshape.manifest")
    proto.metadata_props.add(key="sinshape.manifest", value=manifest.replace('"noise_amp": 1', '"noise_amp": 2'))
    path.write_bytes(fmt.seal(proto.SerializeToString()))
    return path


def load_in_page(page, files) -> list:
    """Each file loaded by the browser runtime: 'loaded', or its error message."""
    return page.evaluate("""async (files) => {
      const s = await import('./static/sinshape/runtime.js');
      const out = [];
      for (const [name, data] of files) {
        try {
          await s.loadModel(Uint8Array.from(atob(data), (c) => c.charCodeAt(0)), { name });
          out.push('loaded');
        } catch (error) {
          out.push(error.message);
        }
      }
      return out;
    }""", [[f.name, base64.b64encode(f.read_bytes()).decode()] for f in files])


def test_files_are_refused_as_the_python_loader_refuses_them(site_page, tmp_path):
    page = site_page
    page.goto(f"{page.base}/?seed=3")
    wait_done(page)
    foreign = foreign_model(tmp_path / "foreign.onnx")
    page.set_input_files("#file", foreign)
    page.wait_for_function("document.body.dataset.state === 'error'", timeout=30_000)
    assert page.is_visible("#error")
    assert page.text_content("#error") == "foreign.onnx: an ONNX model, but not a sinshape model (no sinshape.manifest metadata)"
    # A sinshape file of the user's own is checked and sampled, beside the listed models.
    mine = tmp_path / "mine.onnx"
    mine.write_bytes(TERRAIN.read_bytes())
    page.set_input_files("#file", mine)
    page.wait_for_function("document.body.dataset.state === 'ready' && location.search.includes('mine')",
                           timeout=30_000)
    assert page.input_value("#model") == "mine (file)" and not page.is_visible("#error")
    assert len(page.locator("#model option").all()) == 3  # terrain, towerruins, the file

    (tmp_path / "text.onnx").write_text("hello, not a model")
    (tmp_path / "empty.onnx").write_bytes(b"")
    # Made from the tiny test model: the page hashes every byte of each (its seal), a quarter of the terrain's.
    altered = lambda path, change, seal=True: altered_terrain(path, change, seal, source=TINY)  # noqa: E731
    files = [foreign, tmp_path / "text.onnx", tmp_path / "empty.onnx",
             altered(tmp_path / "newer.onnx", newer_version),
             altered(tmp_path / "external.onnx", external_data),
             altered(tmp_path / "op.onnx", foreign_op),
             altered(tmp_path / "flipped.onnx", flipped_weight, seal=False),
             altered(tmp_path / "sealed.onnx", edit_manifest(lambda m: m.update(seed_note="edited")), seal=False),
             altered(tmp_path / "unsealed.onnx", drop_seal, seal=False),
             altered(tmp_path / "amp.onnx", edit_manifest(lambda m: m["levels"][1].update(noise_amp=1e30))),
             altered(tmp_path / "origin.onnx", edit_manifest(lambda m: m["frame"].update(origin=[1e300, 0, 0]))),
             altered(tmp_path / "source.onnx", edit_manifest(lambda m: m.update(source=None))),
             altered(tmp_path / "config.onnx", edit_manifest(lambda m: m["config"].update(iters={"a": 1}))),
             altered(tmp_path / "seconds.onnx", edit_manifest(lambda m: m["training"].update(level_seconds=5))),
             altered(tmp_path / "shrink.onnx", edit_manifest(lambda m: m["levels"][1].update(size=[9, 9, 9]))),
             altered(tmp_path / "spacing.onnx", edit_manifest(lambda m: m["frame"].update(spacing=[1e-300, 1, 1]))),
             altered(tmp_path / "step.onnx", edit_manifest(lambda m: m["frame"].update(origin=[1e9, 0, 0]))),
             sealed_twice(tmp_path / "twice.onnx"),
             altered(tmp_path / "weight.onnx", weight_twice)]
    messages = load_in_page(page, files)
    for path, message in zip(files, messages):
        with pytest.raises(InputError) as python:
            load.load_model(path)
        assert message == str(python.value).replace(str(path), path.name)
    assert "not an ONNX file" in messages[1] and "newer than this sinshape reads" in messages[3]
    assert "external data" in messages[4] and "(Softmax)" in messages[5]
    assert all("do not match the SHA-256 sealed at its end" in m for m in messages[6:8])
    assert "ends with a seal" in messages[8] and "noise_amp" in messages[9] and "origin" in messages[10]
    assert "source" in messages[11] and "config" in messages[12] and "training seconds" in messages[13]
    assert "levels grow" in messages[14] and "spacing" in messages[15] and "float32's step" in messages[16]
    assert "corrupt model: it holds sinshape.manifest twice" in messages[17]
    assert "corrupt model: it holds the weight " in messages[18] and messages[18].endswith(" twice")
    # The page reads formats 3 to 5 only (sinrun serve and export-web seal older models on the way out).
    (message,) = load_in_page(page, [Path(__file__).parent / "data" / "tiny_v2.onnx"])
    assert message == "tiny_v2.onnx: a format 2 model; the browser reads formats 3 to 5, which `sinrun serve` and " \
                      "`sinrun export-web` write from it"


def test_the_serve_page_switches_to_the_browser(browser):
    """On `sinrun serve` (COOP/COEP sent: WASM on threads) the switch samples the same shape here."""
    pytest.importorskip("fastapi")
    from test_serve import running_server

    with running_server("terrain") as (base, _):
        page = open_page(browser, base)
        page.goto(f"{base}/?seed=3&where=server")
        assert wait_done(page) == "ready"
        server_faces = page.text_content("#status").split()[0]
        assert not page.is_visible("#backend")
        page.select_option("#where", "browser")
        page.wait_for_function("location.search.includes('where=browser') && document.body.dataset.state === 'ready'",
                               timeout=60_000)
        status = page.text_content("#status")
        assert status.endswith("in this browser · without its relief: sinrun serve makes them")
        faces = int(status.split()[0].replace(",", ""))
        assert abs(faces - int(server_faces.replace(",", ""))) <= faces / 1000
        assert page.evaluate("crossOriginIsolated")
        backend = page.text_content("#backend")
        assert re.search(r"on WASM, \d+ threads?; model loaded and checked in \d+\.\d\d s$", backend) and "not cross-origin isolated" not in backend
        assert not page.errors and not page.outside


def run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_export_web_writes_replaces_and_refuses(tmp_path):
    out = tmp_path / "site"
    result = run("export-web", "terrain", "-o", out)
    assert result.exit_code == 0, result.output
    assert f"python {out / 'serve.py'}" in result.output
    assert {"index.html", "models.json", "serve.py", "_headers", "README.txt"} <= {p.name for p in out.iterdir()}
    assert (out / "models" / "terrain.onnx").read_bytes() == TERRAIN.read_bytes()
    assert 'data-site="static"' in (out / "index.html").read_text()
    # onnxruntime-web's WASM-only build, and nothing of the WebGPU (JSEP) build.
    vendored = {p.name for p in (out / "static" / "vendor" / "onnxruntime-web").iterdir()}
    assert {"ort.wasm.min.mjs", "ort-wasm-simd-threaded.mjs", "ort-wasm-simd-threaded.wasm", "LICENSE"} <= vendored
    assert not [name for name in vendored if "jsep" in name or name.startswith("ort.min.")]
    # A previous export is replaced; any other folder with files is refused, untouched.
    assert run("export-web", "terrain", "-o", out).exit_code == 0
    other = tmp_path / "other"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert_one_line_error(run("export-web", "terrain", "-o", other), "holds files export-web did not write (keep.txt)")
    assert [p.name for p in other.iterdir()] == ["keep.txt"]
    # A bad model: one line, nothing written.
    assert_one_line_error(run("export-web", foreign_model(tmp_path / "foreign.onnx"), "-o", tmp_path / "new"),
                          "not a sinshape model")
    assert not (tmp_path / "new").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign.onnx", "other", "site"]


def test_export_web_help():
    result = run("export-web", "--help")
    assert result.exit_code == 0 and "static web site" in result.output and "--output" in result.output


def test_export_web_refuses_a_model_inside_the_folder_it_replaces(tmp_path):
    out = tmp_path / "site"
    assert run("export-web", "terrain", "-o", out).exit_code == 0
    inside = out / "models" / "terrain.onnx"
    assert_one_line_error(run("export-web", inside, "-o", out), "inside the folder")
    assert inside.read_bytes() == TERRAIN.read_bytes()
