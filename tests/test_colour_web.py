"""Colour and relief on the page, in Debian's headless chromium: the Python
runtime makes them (the browser's runtime makes geometry only, docs/WEB.md,
"One runtime"), so the page shows the server's colours as the Python runtime
wrote them, in world mode too; on the browser back end a coloured model's
geometry is the Python runtime's, shown grey, and the status line says what
was left out and where to get it."""

from pathlib import Path

import numpy as np
import pytest

from browser import open_page, wait_world
from test_web import browser, playwright, wait_done  # noqa: F401 (the fixtures of the browser's tests)
from sinshape.runtime import load, request, write

COLOUR_ONNX = Path(__file__).parent / "data" / "tiny_colour.onnx"  # format 5: colour tiles
HEAD_ONNX = Path(__file__).parent / "data" / "tiny_colour_v4.onnx"  # format 4: a colour head
RELIEF_ONNX = Path(__file__).parent / "data" / "tiny_relief.onnx"  # format 5: geometry only, relief tiles

SHOWN_JS = """() => { let shown = null; window.sinshapeView.scene.traverse((n) => { if (n.isMesh && n.visible && !shown)
  shown = { positions: Array.from(n.geometry.attributes.position.array),
            colours: n.geometry.attributes.color ? Array.from(n.geometry.attributes.color.array) : null }; }); return shown; }"""


def linear(srgb) -> np.ndarray:
    """sRGB colours in [0, 1] as the linear ones glTF and three.js hold."""
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


@pytest.fixture(scope="module")
def served(browser):  # noqa: F811
    pytest.importorskip("fastapi")
    from test_serve import running_server

    with running_server(COLOUR_ONNX, HEAD_ONNX, RELIEF_ONNX) as (base, _):
        page = open_page(browser, base)
        page.base = base
        yield page
        page.close()


@pytest.mark.parametrize("onnx", [COLOUR_ONNX, HEAD_ONNX], ids=["tiles", "head"])
def test_the_page_shows_the_python_runtimes_colours(served, onnx):
    """On the server back end a coloured sample's vertex colours are those the Python runtime writes
    for the same request (within the step of a .glb's linear bytes)."""
    page = served
    page.goto(f"{page.base}/?model={onnx.stem}&seed=3&scale=2&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    shown = page.evaluate(SHOWN_JS)
    assert shown["colours"], "no vertex colours shown"
    _, made = write.request_bytes(load.load_model(onnx), request.SampleRequest(seed=3, scale=2.0), "s.glb")
    expected = linear(made.visual.vertex_colors[:, :3] / 255)
    got = np.reshape(shown["colours"], (-1, 3))
    assert len(got) == len(expected)
    # The same colours, as many of each: within a step of the .glb's linear bytes (COLOR_0).
    assert np.abs(np.sort(got, axis=0) - np.sort(expected, axis=0)).max() <= 1.01 / 255
    assert expected.std(axis=0).max() > 0.01  # colours that vary, not one grey
    assert not page.errors and not page.outside


@pytest.mark.parametrize("onnx, left", [(COLOUR_ONNX, "colour and relief"), (HEAD_ONNX, "colour"), (RELIEF_ONNX, "relief")])
def test_the_browser_makes_a_coloured_models_geometry_and_says_what_it_left_out(served, onnx, left):
    """On the browser back end: the same faces as the Python runtime's geometry (detail off), no
    vertex colours, and the status line names what the server would add; detail off, it names nothing."""
    page = served
    page.goto(f"{page.base}/?model={onnx.stem}&seed=3&up=z&where=browser")
    assert wait_done(page) == "ready", page.text_content("#error")
    shown = page.evaluate(SHOWN_JS)
    assert shown["colours"] is None
    _, plain = write.request_bytes(load.load_model(onnx), request.SampleRequest(seed=3, detail=False), "s.ply")
    assert abs(len(shown["positions"]) // 3 - len(plain.vertices)) <= 2  # the runtimes agree within 1e-4 (test_web.py)
    status = page.text_content("#status")
    assert f"without its {left}: sinrun serve makes them" in status
    assert not page.errors and not page.outside


def test_world_tiles_in_the_page_carry_the_servers_colour(served):
    """Every world tile of a coloured model is coloured in world mode, from the tile route."""
    page = served
    page.goto(f"{page.base}/?model={COLOUR_ONNX.stem}&seed=3&scale=1&up=z")
    assert wait_done(page) == "ready", page.text_content("#error")
    page.select_option("#edit", "world")
    page.select_option("#reach", "1")
    wait_world(page)
    page.wait_for_function("window.sinshapeView.world.status().tiles.length === 9", timeout=120_000)  # each at full detail
    status = page.evaluate("window.sinshapeView.world.status()")
    made = [t for t in status["tiles"] if t[2] > 0]
    assert made and status["coloured"] == len(made)
    assert not page.errors and not page.outside


def test_the_browser_back_end_offers_no_world_mode(served):
    """The world mode is the server's: on the browser back end its choice is disabled, and a link
    asking for it opens the plain sample."""
    page = served
    page.goto(f"{page.base}/?model=terrain&seed=3&up=z&where=browser&edit=world")
    assert wait_done(page) == "ready", page.text_content("#error")
    assert page.evaluate("document.querySelector('#edit option[value=world]').disabled")
    assert page.input_value("#edit") == "" and not page.evaluate("window.sinshapeView.world.status()")
    page.select_option("#where", "server")
    page.wait_for_function("!document.querySelector('#edit option[value=world]').disabled")
