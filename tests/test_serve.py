"""`sinrun serve`: the HTTP API against a real server on a free loopback port."""

import contextlib
import gzip
import http.client
import io
import json
import os
import re
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from browser import GUARD_SECONDS
from sinshape import models
from sinshape.cli.main import cli
from sinshape.runtime.options import OPTION
from test_cli_train import assert_one_line_error

pytest.importorskip("fastapi", reason="needs the serve extra: pip install 'sinshape[serve]'")
pytest.importorskip("uvicorn", reason="needs the serve extra: pip install 'sinshape[serve]'")

TERRAIN = (64, 41, 15)  # the shipped terrain model's training size


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get(url: str, headers=None) -> tuple:
    """(status, headers, body) of a GET, 4xx and 5xx included."""
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, response.headers, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.headers, error.read()


@contextlib.contextmanager
def running_server(*args):
    """`sinrun serve ARGS` in a child process on a free port: yields (base URL, process)."""
    port = free_port()
    code = "from sinshape.cli.main import main; main()"
    process = subprocess.Popen([sys.executable, "-c", code, "serve", *map(str, args), "--port", str(port)],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + GUARD_SECONDS
        while True:
            if process.poll() is not None:
                raise AssertionError(f"the server stopped: {process.stdout.read()}")
            with contextlib.suppress(OSError):
                if get(f"{base}/health")[0] == 200:
                    break
            assert time.monotonic() < deadline, f"the server did not answer /health within {GUARD_SECONDS} s"
            time.sleep(0.1)
        yield base, process
    finally:
        process.terminate()
        output = process.communicate(timeout=20)[0]
        assert "Traceback" not in output, output


@pytest.fixture(scope="module")
def server():
    with running_server("terrain", "--threads", 2) as running:
        yield running


def memory_mb(pid: int, field: str) -> float:
    """A memory figure of a process from /proc (VmHWM: its peak resident memory), in MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {field} in /proc")


def peak_mb(pid: int, work) -> float:
    """The process's peak resident memory while work() runs (its peak reset
    first: /proc/PID/clear_refs), in MB."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")
    work()
    return memory_mb(pid, "VmHWM")


def sample_url(base, model="terrain", **query) -> str:
    return f"{base}/api/models/{model}/sample?" + "&".join(f"{k}={v}" for k, v in query.items())


def test_health_models_and_manifest(server):
    base, _ = server
    status, _, body = get(f"{base}/health")
    assert status == 200 and json.loads(body)["status"] == "ok"
    status, _, body = get(f"{base}/api/models")
    assert status == 200 and json.loads(body) == [
        {"name": "terrain", "size": list(TERRAIN), "levels": 4, "up": "z", "arrange": "blend", "training_input": "terrain.obj"}]
    status, _, body = get(f"{base}/api/models/terrain")
    summary = json.loads(body)
    assert status == 200 and summary["levels"] == len(summary["sizes"]) == 4
    assert summary["sizes"][-1] == list(TERRAIN) and summary["training_input"]["name"] == "terrain.obj"
    assert summary["config"]["res"] == 64 and summary["noise_amps"][0] == 1.0


def test_openapi_describes_every_route(server):
    status, _, body = get(f"{server[0]}/openapi.json")
    paths = json.loads(body)["paths"]
    assert status == 200
    assert {"/health", "/api/models", "/api/models/{name}", "/api/models/{name}/sample"} <= set(paths)
    assert "post" in paths["/api/models/{name}/sample"]
    params = {p["name"] for p in paths["/api/models/{name}/sample"]["get"]["parameters"]}
    # and the options of a sample request, which tests/test_options.py holds to their table
    assert params - set(OPTION) == {"name", "format", "lods", "texture", "ao", "height", "collision", "hulls",
                                       "naming", "quantise", "compress", "ktx2"} \
        and {"seed", "smooth"} <= params


def test_the_page_and_its_offline_scripts(server):
    base, _ = server
    status, headers, body = get(f"{base}/")
    assert status == 200 and b'id="download"' in body and headers["Content-Type"].startswith("text/html")
    assert b"http" not in body.split(b"<body")[0], "the page's head must load nothing from the network"
    for path in ("viewer.js", "vendor/three/three.module.js", "vendor/three/three.core.js",
                 "vendor/three/addons/loaders/GLTFLoader.js", "vendor/three/addons/controls/OrbitControls.js",
                 "vendor/three/LICENSE"):
        assert get(f"{base}/static/{path}")[0] == 200, path


def test_the_model_file_and_isolation_headers_for_the_browser(server):
    base, _ = server
    status, headers, body = get(f"{base}/api/models/terrain/onnx")
    assert status == 200 and body == models.find("terrain").read_bytes()
    assert headers["Cache-Control"] == "no-cache" and headers["ETag"].startswith('"')
    assert get(f"{base}/api/models/terrain/onnx", {"If-None-Match": headers["ETag"]})[:3:2] == (304, b"")
    status, packed, _ = get(f"{base}/api/models/terrain/onnx", {"Accept-Encoding": "gzip"})
    assert status == 200 and packed["ETag"] == f"W/{headers['ETag']}"  # the browser's copy, gzipped, revalidates too
    assert get(f"{base}/api/models/terrain/onnx", {"Accept-Encoding": "gzip", "If-None-Match": packed["ETag"]})[0] == 304
    for url in (f"{base}/", f"{base}/static/sinshape/runtime.js", f"{base}/api/models"):
        status, headers, _ = get(url)
        assert status == 200 and headers["Cross-Origin-Opener-Policy"] == "same-origin"
        assert headers["Cross-Origin-Embedder-Policy"] == "require-corp"
    for path in ("sinshape/model.js", "vendor/onnxruntime-web/ort.wasm.min.mjs",
                 "vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm", "vendor/onnxruntime-web/LICENSE"):
        assert get(f"{base}/static/{path}")[0] == 200, path
    status, _, body = get(f"{base}/api/models/nope/onnx")
    assert status == 404 and "unknown model 'nope'" in json.loads(body)["detail"]


def test_answers_are_gzip_compressed_for_clients_that_accept_it(server):
    """The 14 MB WASM and a sample go out gzip-compressed when the client
    accepts it, as they are when it does not; a compressed answer's ETag is
    weak and still revalidates; static files say Cache-Control: no-cache."""
    base, _ = server
    static = Path(__file__).parents[1] / "serve" / "static"
    wasm = "vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm"
    for path, kind in ((wasm, "application/wasm"), ("vendor/three/three.core.js", "text/javascript"),
                       ("vendor/onnxruntime-web/ort.wasm.min.mjs", "text/javascript")):
        status, headers, plain = get(f"{base}/static/{path}")
        assert status == 200 and "Content-Encoding" not in headers and plain == (static / path).read_bytes()
        assert headers["Cache-Control"] == "no-cache" and "Accept-Encoding" in headers["Vary"]
        status, headers, packed = get(f"{base}/static/{path}", {"Accept-Encoding": "gzip, deflate"})
        assert status == 200 and headers["Content-Encoding"] == "gzip" and headers["Content-Type"].startswith(kind)
        assert len(packed) < len(plain) / 3 and gzip.decompress(packed) == plain, path
        assert "Accept-Encoding" in headers["Vary"] and headers["Cross-Origin-Embedder-Policy"] == "require-corp"
        assert headers["Cache-Control"] == "no-cache" and headers["ETag"].startswith("W/")
        again = get(f"{base}/static/{path}", {"Accept-Encoding": "gzip", "If-None-Match": headers["ETag"]})
        assert again[0] == 304 and again[1]["Cache-Control"] == "no-cache" and not again[2]
    status, headers, _ = get(f"{base}/", {"Accept-Encoding": "gzip"})
    assert status == 200 and headers["Content-Encoding"] == "gzip" and headers["Cache-Control"] == "no-cache"
    assert get(f"{base}/static/{wasm}", {"Accept-Encoding": "gzip;q=0"})[1].get("Content-Encoding") is None
    url = sample_url(base, seed=21, scale=2)
    _, plain_headers, plain = get(url)
    status, headers, packed = get(url, {"Accept-Encoding": "gzip"})
    assert status == 200 and headers["Content-Encoding"] == "gzip" and gzip.decompress(packed) == plain
    assert len(packed) < len(plain) and headers["X-Faces"] == plain_headers["X-Faces"]
    assert headers["ETag"] == f"W/{plain_headers['ETag']}"  # a strong tag would name gzip's bytes as the file's
    assert get(url, {"Accept-Encoding": "gzip", "If-None-Match": headers["ETag"]})[0] == 304


def asgi_get(app, path: str, headers=None) -> tuple:
    """(status, headers, body) of a GET answered by the ASGI `app` itself, on the running loop."""
    async def run():
        sent = []
        scope = {"type": "http", "asgi": {"version": "3.0", "spec_version": "2.4"}, "http_version": "1.1",
                 "method": "GET", "scheme": "http", "path": path, "raw_path": path.encode(), "query_string": b"",
                 "root_path": "", "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 80),
                 "headers": [(b"host", b"127.0.0.1"), *((k.lower().encode(), v.encode()) for k, v in (headers or {}).items())]}

        async def receive():
            return {"type": "http.request", "body": b"", "more_body": False}

        async def send(message):
            sent.append(message)

        await app(scope, receive, send)
        start = next(m for m in sent if m["type"] == "http.response.start")
        answer = {k.decode().lower(): v.decode() for k, v in start["headers"]}
        return start["status"], answer, b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return run()


def test_static_files_are_gzipped_once_and_kept(monkeypatch):
    """The WASM is compressed on its first request only: later ones, and a
    client asking at the same time, are given the same bytes from memory."""
    import asyncio

    from sinshape.runtime import load_model
    from sinshape.serve import app as served, compress

    made = []
    real = compress.packed
    monkeypatch.setattr(compress, "packed", lambda data: made.append(len(data)) or real(data))
    application = served.create_app({"terrain": load_model(models.find("terrain"), threads=1)}, slots=1)
    wasm = "/static/vendor/onnxruntime-web/ort-wasm-simd-threaded.wasm"
    plain = (Path(served.STATIC) / wasm.removeprefix("/static/")).read_bytes()

    async def requests():
        together = await asyncio.gather(*(asgi_get(application, wasm, {"Accept-Encoding": "gzip"}) for _ in range(3)))
        later = await asgi_get(application, wasm, {"Accept-Encoding": "gzip"})
        return [*together, later, await asgi_get(application, wasm)]

    *packed, asked_plainly = asyncio.run(requests())
    assert made == [len(plain)]  # one compression of the WASM for four requests that accept gzip
    for status, headers, data in packed:
        assert status == 200 and headers["content-encoding"] == "gzip" and headers["cache-control"] == "no-cache"
        assert headers["content-type"] == "application/wasm" and int(headers["content-length"]) == len(data)
        assert data == packed[0][2] and gzip.decompress(data) == plain
    status, headers, body = asked_plainly
    assert status == 200 and "content-encoding" not in headers and body == plain


def test_model_files_are_served_as_checked_at_start_sealed_as_format_3(tmp_path):
    """A format-2 model goes out sealed as format 3 (the browser checks seals
    only), and what was checked at start-up is served even after the file changes."""
    from sinshape.runtime import load_model

    old = tmp_path / "old.onnx"
    old.write_bytes((Path(__file__).parent / "data" / "tiny_v2.onnx").read_bytes())
    with running_server(old, "--threads", 1) as (base, _):
        old.write_bytes(b"replaced after start-up")
        status, _, body = get(f"{base}/api/models/old/onnx")
        old.unlink()
        assert status == 200 and get(f"{base}/api/models/old/onnx")[2] == body
    served = tmp_path / "served.onnx"
    served.write_bytes(body)
    assert load_model(served, threads=1).manifest.raw["format_version"] == 3


def test_keep_composes_as_the_command_line_does(server, tmp_path):
    base, _ = server
    part = "3:0%25,0%25,0%25:50%25,100%25,100%25"  # 3:0%,0%,0%:50%,100%,100%, escaped
    status, headers, body = get(sample_url(base, seed=7, keep=part, format="npz"))
    assert status == 200 and "keep3" in headers["Content-Disposition"]
    out = tmp_path / "k.npz"
    result = CliRunner().invoke(cli, ["sample", "terrain", "--seed", "7", "--keep", "3:0%,0%,0%:50%,100%,100%",
                                      "-o", str(out)])
    assert result.exit_code == 0 and body == out.read_bytes()
    status, _, body = get(sample_url(base, seed=7, keep="3:0%25,0%25,0%25:150%25,100%25,100%25"))
    assert status == 400 and "leaves the sample" in json.loads(body)["detail"]
    status, headers, body = get(sample_url(base, seed=7, grow="2,1,1", anchor="0.5,0,0", format="npz"))
    result = CliRunner().invoke(cli, ["sample", "terrain", "--seed", "7", "--grow", "2,1,1", "--anchor", "0.5,0,0",
                                      "-o", str(out)])
    assert status == 200 and "grow2x1x1" in headers["Content-Disposition"] and body == out.read_bytes()
    status, _, body = get(sample_url(base, seed=7, grow="0.5"))
    assert status == 400 and "at least 1" in json.loads(body)["detail"]


def test_edits_that_do_not_go_together_are_a_400_saying_so(server):
    status, _, body = get(sample_url(server[0], seed=7, grow="2", keep="3:0%25,0%25,0%25:50%25,100%25,100%25"))
    assert status == 400 and json.loads(body)["detail"] == "give one of keep, grow"


def post(url: str, body: bytes) -> tuple:
    request = urllib.request.Request(url, data=body, method="POST",
                                     headers={"Content-Type": "application/octet-stream"})
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            return response.status, response.headers, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.headers, error.read()


def test_a_layout_uploaded_samples_as_the_command_line_does(server, tmp_path):
    base, _ = server
    vox, out = tmp_path / "l.vox", tmp_path / "s.npz"
    assert CliRunner().invoke(cli, ["layout", "terrain", "--seed", "4", "-o", str(vox)]).exit_code == 0
    assert CliRunner().invoke(cli, ["sample", "terrain", "--seed", "4", "--layout", str(vox), "-o", str(out)]).exit_code == 0
    status, headers, body = post(sample_url(base, seed=4, format="npz"), vox.read_bytes())
    assert status == 200 and "layout" in headers["Content-Disposition"] and body == out.read_bytes()
    assert post(sample_url(base, seed=4, format="npz"), vox.read_bytes())[1]["X-Cache"] == "hit"
    status, _, body = post(sample_url(base, seed=4), b"not a layout")
    assert status == 400 and "neither a MagicaVoxel .vox nor an .npz" in json.loads(body)["detail"]
    status, _, body = post(sample_url(base, seed=4), vox.read_bytes()[:40])
    assert status == 400 and "not a readable MagicaVoxel file" in json.loads(body)["detail"]



def raw_post(base: str, path: str, headers: dict, body: bytes = b"") -> tuple:
    """(status, detail) of a POST with exactly these headers and `body` as
    given (chunked already, or shorter than its declared length): the answer
    is read without sending more."""
    connection = http.client.HTTPConnection(base.removeprefix("http://"), timeout=GUARD_SECONDS)
    try:
        connection.putrequest("POST", path)
        for name, value in headers.items():
            connection.putheader(name, value)
        connection.endheaders(body)
        answer = connection.getresponse()
        return answer.status, json.loads(answer.read())["detail"]
    finally:
        connection.close()


CHUNKED = {"Transfer-Encoding": "chunked"}
UPLOADS = [("/api/models/terrain/sample?seed=1", "the layout file"),
           ("/api/models/terrain/tile?i=0&j=0", "the height map")]


@pytest.mark.parametrize("path, what", UPLOADS)
def test_an_upload_is_refused_by_its_declared_length_before_it_is_read(server, path, what):
    """A 400 MB body was read whole (800 MB of the server's memory) before
    its 4 MB test: now the answer comes with none of the body sent."""
    base, _ = server
    status, detail = raw_post(base, path, {"Content-Length": 400 << 20})
    assert status == 413 and detail == f"send {what} as the request body (1 byte to 4 MB); it declares 400.0 MB"


@pytest.mark.parametrize("path, what", UPLOADS)
def test_an_upload_without_a_length_is_counted_as_it_arrives(server, path, what):
    base, process = server
    chunk = b"x" * (64 << 10)
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(65)) + b"0\r\n\r\n"
    grown = peak_mb(process.pid, lambda: raw_post(base, path, CHUNKED, body)) - memory_mb(
        process.pid, "VmRSS")
    assert raw_post(base, path, CHUNKED, body) == (
        413, f"send {what} as the request body (1 byte to 4 MB); it sent more")
    assert grown < 32, f"the server grew by {grown:.0f} MB for a 4 MB body"
    assert raw_post(base, path, {"Content-Length": 0}) == (400, f"send {what} as the request body (1 byte to 4 MB)")


def test_a_sample_is_the_file_sinrun_sample_writes(server, tmp_path):
    status, headers, body = get(sample_url(server[0], seed=5, size="1.5,1,1", smooth=2, format="ply"))
    assert status == 200
    assert headers["Content-Disposition"] == 'attachment; filename="terrain_seed5_size1.5x1x1_smooth2.ply"'
    out = tmp_path / "s.ply"
    result = CliRunner().invoke(cli, ["sample", "terrain", "--seed", "5", "--size", "1.5,1,1", "--smooth", "2",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    assert body == out.read_bytes()
    assert int(headers["X-Faces"]) == len(trimesh.load(out).faces) > 1000


@pytest.mark.parametrize("fmt", ["glb", "ply", "obj", "stl", "off", "npz"])
def test_every_format_loads(server, fmt):
    status, headers, body = get(sample_url(server[0], seed=2, format=fmt))
    assert status == 200 and headers["Content-Disposition"].endswith(f'seed2.{fmt}"')
    if fmt == "npz":
        with np.load(io.BytesIO(body)) as data:
            assert data["occupancy"].shape == TERRAIN and 0 <= data["occupancy"].min() < 0.5 < data["occupancy"].max()
    else:
        mesh = trimesh.load(io.BytesIO(body), file_type=fmt, force="mesh")
        assert len(mesh.faces) == int(headers["X-Faces"]) > 1000


def test_a_repeated_request_is_a_cache_hit(server):
    """The hit is not made again: the server's CPU time over three hits is
    under a third of the miss's, measured one after the other (a terrain
    sample at scale 2 costs it 0.15 s of CPU here, three hits 0.01 s, the
    clock's tick; CPU time, not the clock, so that a busy machine stretches
    neither)."""
    base, process = server
    url = sample_url(base, seed=11, scale=2)
    started = cpu_seconds(process.pid)
    status, first, body = get(url)
    missed = cpu_seconds(process.pid) - started
    started = cpu_seconds(process.pid)
    for _ in range(3):
        status2, second, body2 = get(url.replace("scale=2", "scale=2.0"))  # the same request, normalised
        assert status2 == 200 and body2 == body and second["X-Cache"] == "hit"
    hits = cpu_seconds(process.pid) - started
    assert status == 200 and first["X-Cache"] == "miss"
    assert first["ETag"] == second["ETag"] and first["ETag"].startswith('"')  # strong: no W/
    assert hits < missed / 3, (hits, missed)
    status, headers, body = get(url, {"If-None-Match": first["ETag"]})
    assert status == 304 and body == b"" and headers["ETag"] == first["ETag"]
    other = get(sample_url(server[0], seed=12, scale=2))[1]
    assert other["ETag"] != first["ETag"]


@pytest.mark.parametrize("query, status, fragment", [
    ({"seed": "abc"}, 422, "seed: Input should be a valid integer"),
    ({"seed": "-1"}, 422, "seed: Input should be greater than or equal to 0"),
    ({"seed": str(2**63)}, 422, "seed: Input should be less than"),
    ({"scale": "0"}, 422, "scale: Input should be greater than 0"),
    ({"scale": "nan"}, 422, "scale: Input should be a finite number"),
    ({"scale": "1e9"}, 400, "at most 65536 points per axis"),
    ({"scale": "1000", "format": "npz"}, 413, "GiB of memory (limit"),
    ({"size": "1000"}, 413, "needs about"),
    ({"size": "abc"}, 400, "give one or three positive factors"),
    ({"size": "1,1"}, 400, "give one or three positive factors"),
    ({"size": "0,1,1"}, 400, "give one or three positive factors"),
    ({"size": "1e308"}, 400, "the most a sample may have per axis"),
    ({"smooth": "-3"}, 422, "smooth: Input should be greater than or equal to 0"),
    ({"format": "xyz"}, 422, "format: Input should be 'ply', 'obj'"),
    ({"model": "nope"}, 404, "unknown model 'nope'; this server has terrain"),
])
def test_bad_values_are_4xx_with_one_line(server, query, status, fragment):
    base, _ = server
    got, headers, body = get(sample_url(base, **query))
    assert got == status and headers["Content-Type"] == "application/json"
    detail = json.loads(body)["detail"]
    assert isinstance(detail, str) and "\n" not in detail and fragment in detail, detail
    assert get(f"{base}/health")[0] == 200


def test_twenty_concurrent_requests(server):
    """All answered, correctly: the same seed gives the same bytes, different
    seeds different meshes. Memory stays bounded by the slots (2 here): at
    most two samples were made at once, and the server's peak with twenty
    requests for ten seeds at once is at most 1.5 times its peak with two at
    once, measured side by side (210 and 260 MB here, the twenty answers'
    bytes among them; unbounded, ten samples in flight would double it). A
    peak of resident memory, which a busy machine does not move."""
    base, process = server
    seeds = [200 + i % 10 for i in range(20)]
    with ThreadPoolExecutor(20) as pool:
        two = peak_mb(process.pid, lambda: list(pool.map(lambda s: get(sample_url(base, seed=s, scale=2)), [190, 191])))
        answers = []
        twenty = peak_mb(process.pid, lambda: answers.extend(
            pool.map(lambda s: get(sample_url(base, seed=s, scale=2)), seeds)))
    assert [status for status, _, _ in answers] == [200] * 20
    bodies = {}
    for seed, (_, headers, body) in zip(seeds, answers):
        assert bodies.setdefault(seed, body) == body
    meshes = [trimesh.load(io.BytesIO(body), file_type="glb", force="mesh") for body in bodies.values()]
    assert len({len(m.faces) for m in meshes}) > 5 and all(len(m.faces) > 1000 for m in meshes)
    assert twenty <= 1.5 * two, (twenty, two)
    health = json.loads(get(f"{base}/health")[2])
    assert health["in_flight"] == health["sampling"] == 0 and 1 <= health["most_sampling"] <= health["slots"]


def cpu_seconds(pid: int) -> float:
    """The CPU time a process has used (user and system, all its threads), from /proc."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def a_smaller_sample_cpu_seconds() -> float:
    """The CPU time of one whole terrain sample at scale 8 in this process,
    an eighth of the points of one at scale 16: the yardstick that work
    left running after a request ends is measured by, side by side."""
    from sinshape.runtime import load_model, write
    from sinshape.runtime.request import SampleRequest

    model = load_model(models.find("terrain"), threads=2)
    started = time.process_time()
    write.request_bytes(model, SampleRequest(1, scale=8), "yardstick.glb", threads=2)
    return time.process_time() - started


def wait_until_idle(base) -> None:
    """Until no sample is being made (a hang guard only: minutes)."""
    deadline = time.monotonic() + 300
    while json.loads(get(f"{base}/health")[2])["sampling"]:
        assert time.monotonic() < deadline, "the samples never stopped"
        time.sleep(0.05)


def test_a_slow_request_is_cut_off_by_the_time_limit():
    """A 504 within the limit, and the cut-off sample stops at its next
    slab: the server's CPU time from the 504 until its slot is free is less
    than a whole sample at scale 8 costs (measured beside it; 0.3 times
    here), where going on to the end costs 3.6 times (terrain at scale 16).
    CPU time, not the clock: a busy machine stretches the wait, not the work."""
    with running_server("terrain", "--timeout", "0.3") as (base, process):
        status, _, body = get(sample_url(base, seed=1, scale=16))
        cut = cpu_seconds(process.pid)
        assert status == 504 and "longer than the 0.3 s limit" in json.loads(body)["detail"]
        wait_until_idle(base)
        after = cpu_seconds(process.pid) - cut
        yardstick = a_smaller_sample_cpu_seconds()
        assert after < yardstick, (after, yardstick)
        assert get(f"{base}/api/models/terrain")[0] == 200


def test_only_the_allowed_host_names_are_answered(server):
    base, _ = server
    port = base.rsplit(":", 1)[1]
    status, _, body = get(f"{base}/api/models", {"Host": "evil.example.com"})
    assert status == 400 and "does not answer to the host 'evil.example.com'" in json.loads(body)["detail"]
    assert get(f"{base}/api/models", {"Host": f"localhost:{port}"})[0] == 200
    with running_server("terrain", "--allowed-host", "sinshape.test") as (other, _):
        assert get(f"{other}/api/models", {"Host": "sinshape.test"})[0] == 200
        assert get(f"{other}/api/models", {"Host": "evil.example.com"})[0] == 400


def test_a_client_that_leaves_frees_its_slot():
    """Requests whose clients give up after 0.5 s stop their samples (terrain
    at scale 24 takes far longer), so the next request is not kept waiting:
    the server's CPU time after the clients left is less than six times a
    whole sample at scale 8 costs (measured beside it; 1.4-2.2 times here),
    where the samples going on cost twenty times. CPU time, not the clock."""
    with running_server("terrain", "--timeout", "60") as (base, process):
        def impatient(seed):
            try:
                urllib.request.urlopen(sample_url(base, seed=seed, scale=24), timeout=0.5)
            except OSError:
                pass

        with ThreadPoolExecutor(4) as pool:
            list(pool.map(impatient, range(4)))
        left = cpu_seconds(process.pid)
        wait_until_idle(base)
        after = cpu_seconds(process.pid) - left
        yardstick = a_smaller_sample_cpu_seconds()
        assert after < 6 * yardstick, (after, yardstick)
        assert get(sample_url(base, seed=1))[0] == 200


def test_a_timeout_that_is_not_a_positive_number_is_refused():
    for value in ("nan", "-1", "inf"):
        assert_one_line_error(CliRunner().invoke(cli, ["serve", "terrain", "--timeout", value]), "timeout must be")


def test_serve_help_says_loopback_and_no_authentication():
    result = CliRunner().invoke(cli, ["serve", "--help"])
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "no authentication" in text and "[default: 127.0.0.1]" in text and "exposes" in text


def test_serve_refuses_a_taken_port_and_a_missing_model_in_one_line():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert_one_line_error(CliRunner().invoke(cli, ["serve", "terrain", "--port", port]),
                              f"cannot listen on 127.0.0.1:{port}")
    assert_one_line_error(CliRunner().invoke(cli, ["serve", "nope"]), "neither a model file nor a shipped model")
    assert_one_line_error(CliRunner().invoke(cli, ["serve", "missing.onnx"]), "is missing")


def test_serve_without_the_extra_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "uvicorn", None)
    assert_one_line_error(CliRunner().invoke(cli, ["serve"]), "pip install 'sinshape[serve]'")


def test_models_by_name_or_path_and_every_shipped_one_by_default(tmp_path):
    from sinshape.serve import app

    assert list(app.load_models([])) == sorted(models.available())
    copy = tmp_path / "mine.onnx"
    copy.write_bytes(models.find("terrain").read_bytes())
    assert list(app.load_models(["terrain", str(copy)], threads=1)) == ["terrain", "mine"]
    with pytest.raises(app.InputError, match="two models are called 'terrain'"):
        app.load_models(["terrain", str(models.find("terrain"))])


def test_the_runtime_knows_nothing_about_http():
    runtime = Path(__file__).resolve().parents[1] / "runtime"
    web = re.compile(r"^\s*(from|import)\s+(fastapi|starlette|uvicorn|http|urllib|sinshape\.serve)\b", re.M)
    sources = list(runtime.glob("*.py"))
    assert sources and not [source.name for source in sources if web.search(source.read_text())]


def test_a_tile_is_the_runtimes_tile_with_its_corner_and_etag(server):
    from sinshape import models
    from sinshape.runtime import load_model, world_maps, world_tiles, write
    from sinshape.runtime.request import SampleRequest

    base, _ = server
    terrain = load_model(models.find("terrain"), threads=1)
    url = f"{base}/api/models/terrain/tile?seed=4&i=-3&j=7&format=ply"
    status, headers, body = get(url)
    assert status == 200 and headers["X-Tile-Corner"] == ",".join(map(str, world_tiles.tile_corner(terrain, (-3, 7))))
    assert body == write.request_bytes(terrain, SampleRequest(4, tile=(-3, 7), frame="tile"), "t.ply")[0]
    assert headers["Content-Disposition"] == 'attachment; filename="terrain_seed4_tile-3_7.ply"'
    assert get(url, {"If-None-Match": headers["ETag"]})[0] == 304
    params = {p["name"] for p in json.loads(get(f"{base}/openapi.json")[2])["paths"]["/api/models/{name}/tile"]["get"]
              ["parameters"]}
    assert params == {"name", "i", "j", "seed", "scale", "format", "frame", "arrange", "lod", "skirt", "underside", "density",
                      "spacing", "lods", "texture",
                      "ao", "collision", "naming", "quantise", "compress", "ktx2",
                      "models", "models_map", "detail"}
    for query, code, says in (("i=0", 422, "j: Field required"), (f"i={2**62}&j=0", 422, "i: Input should be less"),
                              ("i=100000000&j=0&frame=input", 400, "give frame tile"), ("i=0&j=0&lod=9", 400, "lod must be 0 to 3"),
                              ("i=0&j=0&arrange=spread", 422, "arrange: Input should be 'blend' or 'scatter'")):
        status, _, body = get(f"{base}/api/models/terrain/tile?{query}")
        assert status == code and says in json.loads(body)["detail"], body
    # A world shaped by a height map: the map is the POST's body, the tile the runtime's of that map.
    heights = np.array([[0.0, 30.0], [12.5, 60.0]], np.float32)
    npy = io.BytesIO()
    np.save(npy, heights)
    status, headers, body = post(f"{base}/api/models/terrain/tile?seed=4&i=1&j=0&format=ply&arrange=scatter&lod=1",
                                 npy.getvalue())
    wanted = SampleRequest(4, tile=(1, 0), frame="tile", arrange="scatter", lod=1, heights=world_maps.HeightMap.of(heights))
    assert status == 200 and body == write.request_bytes(terrain, wanted, "t.ply")[0]
    assert "_scatter_map" in headers["Content-Disposition"] and "_lod1." in headers["Content-Disposition"]
    status, _, body = post(f"{base}/api/models/terrain/tile?i=0&j=0", b"GIF89a")
    assert status == 400 and "neither a .npy array nor a .png image" in json.loads(body)["detail"]
    # A world of several models: the others this server's, by name, and the model map as text.
    status, headers, body = get(f"{base}/api/models/terrain/tile?seed=4&i=2&j=1&format=ply&arrange=scatter"
                                f"&models=terrain&models_map=0,1;1,0")
    wanted = SampleRequest(4, tile=(2, 1), frame="tile", arrange="scatter", models=(str(models.find("terrain")),),
                           models_map=world_maps.ModelMap.of([[0, 1], [1, 0]]))
    assert status == 200 and body == write.request_bytes(terrain, wanted, "t.ply")[0]
    for query, code, says in (("models=moon&models_map=0,1", 404, "unknown model 'moon'"),
                              ("models=terrain&models_map=0,1;2", 400, "a model map's text is rows"),
                              ("models=terrain&models_map=0,2", 400, "names model 2"),
                              ("models=terrain", 400, "need a model map")):
        status, _, body = get(f"{base}/api/models/terrain/tile?i=0&j=0&arrange=scatter&{query}")
        assert status == code and says in json.loads(body)["detail"], body
