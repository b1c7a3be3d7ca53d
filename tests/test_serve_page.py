"""The page at / in a real headless browser: Debian's chromium, driven by Playwright."""

import io
import json
import re
import shutil

import numpy as np
import pytest
import trimesh
from PIL import Image

from test_serve import running_server

sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (the test extra)")
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
if not shutil.which(CHROMIUM):
    pytest.skip("needs Debian's chromium (apt-get install chromium; .ci/run does)", allow_module_level=True)

BACKGROUND = np.array([0x20, 0x24, 0x2A])  # the view's background colour (serve/static/viewer.js)
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
    assert "scale: Input should be greater than 0" in page.text_content("#error")
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
    for _ in range(300):  # until the server is making it (at most 30 s)
        if json.loads(get(f"{page.base}/health")[2])["sampling"]:
            break
        page.wait_for_timeout(100)
    page.click("#cancel")
    assert page.evaluate("document.body.dataset.state") == "cancelled" and page.text_content("#status") == "cancelled"
    assert not page.is_visible("#cancel") and not page.is_visible("#error")
    assert [url for url in failed if "/sample?" in url], "the request was not aborted"
    for _ in range(300):  # the server stops at its next slab
        health = json.loads(get(f"{page.base}/health")[2])
        if not health["sampling"]:
            break
        page.wait_for_timeout(100)
    assert health["sampling"] == 0 and health["in_flight"] == 0, health
    for field in ("#sx", "#sy", "#scale"):
        page.fill(field, "1")
    page.click("#show")
    wait_ready(page, 8)
    assert re.fullmatch(r"[\d,]+ faces · \d+\.\d\d s( \(cached\))?", page.text_content("#status"))
    assert not page.errors
