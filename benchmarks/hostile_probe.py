"""The hostile probes, case by case. The fourth's: textured meshes whose
files lie elsewhere or block, glTF structure and images of hostile size,
colour input a user would be surprised by, resumed jobs of another job,
unbounded world blocks and indexes, a tile left by its client, a colour head
that overflows, the exported site's serve.py and a checkpoint that cannot be
written. The fifth's (classes 7-11): maps and models that are pipes,
devices or sparse giants, uploads larger than the route takes, a weight held
twice, messages that name fields, signals at stated points and output
folders of many files.

Each case runs `sinrun` (or a few lines of Python) in a child process, with
a time limit, against whatever sinshape that Python imports, and is "held"
when it behaves as docs/RELIABILITY.md says: a refusal is one `Error:` line,
a non-zero exit, no traceback, no output file, within the time limit (a
hang fails); a case that should work (a valid MTL option, a warning) does
what it should. Prints one row per class and the cases that failed.

    python benchmarks/hostile_probe.py                                  # this checkout
    PYTHONPATH=/tmp/before python benchmarks/hostile_probe.py           # another tree, e.g. before a change
    (/tmp/before/sinshape/{core,prep,runtime,...} linked to that tree's folders)

Needs the train extra (the mesh cases train a tiny model) and Linux (FIFOs,
RLIMIT_FSIZE). Takes a few minutes: the training cases cost seconds each.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "tests" / "data"
TINY = DATA / "tiny.onnx"
TIMEOUT = 120
SINRUN = "from sinshape.cli.main import main; main()"
TRAIN = ["--preset", "tiny", "--iters", "1", "--levels", "1", "--res", "16"]


def textured_obj(folder: Path, mtl: str | None = None, texture: bytes | None = None) -> Path:
    for name in ("box_texture.obj", "box_texture.mtl", "box_texture.png"):
        shutil.copy(DATA / "colour" / name, folder / name)
    if mtl is not None:
        (folder / "box_texture.mtl").write_text(mtl)
    if texture is not None:
        (folder / "box_texture.png").write_bytes(texture)
    return folder / "box_texture.obj"


def glb_json() -> tuple:
    data = (DATA / "colour" / "box_texture.glb").read_bytes()
    length = int.from_bytes(data[12:16], "little")
    return json.loads(data[20:20 + length]), data[20 + length + 8:]


def textured_gltf(folder: Path, change=None) -> Path:
    """The textured box as .gltf + box.bin + tex.png; change(meta) edits its JSON."""
    meta, binary = glb_json()
    meta["buffers"][0]["uri"] = "box.bin"
    view = meta["bufferViews"][meta["images"][0]["bufferView"]]
    (folder / "tex.png").write_bytes(binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]])
    meta["images"][0] = {"uri": "tex.png"}
    (folder / "box.bin").write_bytes(binary)
    if change:
        change(meta)
    (folder / "box.gltf").write_text(json.dumps(meta))
    return folder / "box.gltf"


def png(width: int, height: int, rgb=(0, 0, 0), bits: int = 8, grey: bool = False) -> bytes:
    import struct
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    row = bytes(-(-width * bits // 8)) if grey else bytes(rgb) * width
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, bits, 0 if grey else 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress((b"\0" + row) * height, 9)) + chunk(b"IEND", b""))


def replace_in(path: Path, old: str, new: str) -> Path:
    path.write_text(path.read_text().replace(old, new))
    return path


def fifo(path: Path) -> None:
    path.unlink(missing_ok=True)
    os.mkfifo(path)


def special_map(kind: str, suffix: str, option: str):
    """A world whose map (`option`) is a FIFO, /dev/zero or a link to it."""
    def setup(folder):
        path = Path("/dev/zero") if kind == "device" else folder / f"map{suffix}"
        if kind == "fifo":
            fifo(path)
        elif kind == "link":
            path.symlink_to("/dev/zero")
        scatter = ["--arrange", "scatter"] if option == "--models-map" else []
        return ["world", "terrain", "--tiles", "0:0,0:0", *scatter, option, path, "-o", folder / "out"]
    return setup


def sparse_map(folder):
    return ("python", f"""
import resource, subprocess, sys
with open("{{f}}/s.npy", "wb") as file:
    file.truncate(2 << 30)
result = subprocess.run([sys.executable, "-c", {SINRUN!r}, "world", "terrain", "--tiles", "0:0,0:0", "--map",
                         "{{f}}/s.npy", "-o", "{{f}}/out"], capture_output=True, text=True)
peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
lines = result.stderr.strip().splitlines()
print("HELD" if result.returncode == 1 and len(lines) == 1 and peak < 200 else "FAILED", f"peak {{peak:.0f}} MB:", lines[-1][:120])
""")


def upload(path: str, how: str):
    """A body larger than the route takes, declared (and never sent) or chunked."""
    def setup(folder):
        return ("python", f"""
import http.client, json, socket, subprocess, sys, time
with socket.socket() as free:
    free.bind(("127.0.0.1", 0))
    port = free.getsockname()[1]
server = subprocess.Popen([sys.executable, "-c", {SINRUN!r}, "serve", "terrain", "--port", str(port)],
                          stderr=subprocess.PIPE, text=True)
assert "Ctrl-C stops" in server.stderr.readline()
connection = http.client.HTTPConnection(f"127.0.0.1:{{port}}", timeout=60)
connection.putrequest("POST", {path!r})
if {how!r} == "declared":
    connection.putheader("Content-Length", str(400 << 20))
    connection.endheaders()
else:
    connection.putheader("Transfer-Encoding", "chunked")
    connection.endheaders()
    chunk = b"x" * (64 << 10)
    for _ in range(80):
        connection.send(b"%x\\r\\n%s\\r\\n" % (len(chunk), chunk))
answer = connection.getresponse()
detail = json.loads(answer.read())["detail"]
rss = int(open(f"/proc/{{server.pid}}/status").read().split("VmHWM:")[1].split()[0]) / 1024
server.terminate()
log = server.communicate()[1]
print("HELD" if answer.status == 413 and "Traceback" not in log else "FAILED", answer.status, f"peak {{rss:.0f}} MB:", detail)
""")
    return setup


def doubled_weight(folder):
    """tiny_colour.onnx with a second, all-zero colour_tiles.images, resealed."""
    code = f"""
import onnx, numpy as np
from onnx import numpy_helper
from sinshape.core import manifest
model = onnx.load({str(DATA / "tiny_colour.onnx")!r})
first = next(t for t in model.graph.initializer if t.name == "colour_tiles.images")
model.graph.initializer.append(numpy_helper.from_array(np.zeros_like(numpy_helper.to_array(first)), first.name))
open({str(folder / "twice.onnx")!r}, "wb").write(manifest.seal(model.SerializeToString()))
"""
    subprocess.run([sys.executable, "-c", code], check=True)
    return ["sample", folder / "twice.onnx", "-o", folder / "out.ply"]


def nan_map(folder):
    import numpy as np

    np.save(folder / "nan.npy", np.array([[0.0, np.nan], [np.inf, 1e30]]))
    return ["world", "terrain", "--tiles", "0:0,0:0", "--map", folder / "nan.npy", "-o", folder / "out"]


def many_models(folder):
    return ["world", "terrain", *["terrain"] * 256, "--arrange", "scatter", "--tiles", "0:0,0:0", "-o", folder / "out"]


def stopped_at(point: str, signals: str, args: list):
    """sinrun ARGS sent `signals` at `point` (tests/stop_at.py): one line, the first signal's status, no file."""
    def setup(folder):
        return ("python", f"""
import signal, subprocess, sys, trimesh
trimesh.creation.box((2, 1, 1)).export("{{f}}/box.obj")
result = subprocess.run([sys.executable, {str(ROOT / "tests" / "stop_at.py")!r}, {point!r}, {signals!r},
                         *[a.replace("{{{{f}}}}", "{{f}}") for a in {args!r}]], capture_output=True, text=True,
                        start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
status = 130 if {signals!r}.startswith("INT") else 143
lines = result.stderr.strip().splitlines()
import pathlib
left = [p.name for p in pathlib.Path("{{f}}").iterdir() if p.name != "box.obj"]
print("HELD" if result.returncode == status and "Traceback" not in result.stderr and not left else "FAILED",
      result.returncode, lines[-1][:100] if lines else "", left)
""")
    return setup


# -- cases: (class, name, setup(folder) -> argv for sinrun, or ("python", code); what holds) ------
# What holds: "refused" (one Error line, non-zero exit, no file named "out*"), or a string the
# output must hold with exit 0 ("ok:TEXT"), or one its one Error line must hold ("error:TEXT": a file
# outside the folder refused as such, not after it was read and found not to be an image).

def mtl_case(statement):
    def setup(folder):
        (folder.parent / "secret.png").write_bytes((DATA / "colour" / "box_texture.png").read_bytes())
        path = textured_obj(folder, mtl=f"newmtl painted\nKd 1 1 1\n{statement.format(outside=folder.parent)}\n")
        return ["train", path, "-o", folder / "out.onnx", *TRAIN]
    return setup


def obj_library(name):
    def setup(folder):
        (folder.parent / "x.mtl").write_text("newmtl painted\nmap_Kd secret.png\n")
        path = replace_in(textured_obj(folder), "mtllib box_texture.mtl", f"mtllib {name}")
        return ["train", path, "-o", folder / "out.onnx", *TRAIN]
    return setup


def gltf_case(change, command="train"):
    def setup(folder):
        (folder.parent / "secret.png").write_bytes((DATA / "colour" / "box_texture.png").read_bytes())
        path = textured_gltf(folder, lambda meta: change(meta, folder.parent))
        if command == "render":
            return ["render", path, "-o", folder / "out.png", "--image-size", "32"]
        return ["train", path, "-o", folder / "out.onnx", *TRAIN]
    return setup


def linked_out(folder):
    (folder.parent / "secret.png").write_bytes((DATA / "colour" / "box_texture.png").read_bytes())
    path = textured_obj(folder)
    (folder / "box_texture.png").unlink()
    (folder / "box_texture.png").symlink_to(folder.parent / "secret.png")
    return ["train", path, "-o", folder / "out.onnx", *TRAIN]


def fifo_in(make, which, command="train"):
    """The mesh make(folder) writes, its file `which` replaced by a FIFO, handed to `command`."""
    def setup(folder):
        path = make(folder)
        fifo(folder / which)
        if command == "render":
            return ["render", path, "-o", folder / "out.png", "--image-size", "32"]
        if command == "layout":
            return ["sample", "terrain", "--layout", path, "-o", folder / "out.ply"]
        return ["train", path, "-o", folder / "out.onnx", *TRAIN]
    return setup


def texture_folder(folder):
    path = textured_obj(folder)
    (folder / "box_texture.png").unlink()
    (folder / "box_texture.png").mkdir()
    return ["train", path, "-o", folder / "out.onnx", *TRAIN]


def padded_texture(folder):
    path = textured_obj(folder)
    with open(folder / "box_texture.png", "r+b") as f:
        f.truncate(6 << 30)
    return ["train", path, "-o", folder / "out.onnx", *TRAIN]


def huge_uvs(folder):
    import re

    path = textured_obj(folder)
    path.write_text(re.sub(r"^vt \S+", "vt 3e38", path.read_text(), count=1, flags=re.MULTILINE))
    return ["train", path, "-o", folder / "out.onnx", *TRAIN]


def pixel_bomb(folder):
    """A 16 kB 1-bit PNG of 16384 x 8192 pixels, with 2 GiB available: refused with the figure, and
    the process's peak memory stays under 1 GB."""
    path = textured_obj(folder, texture=png(16384, 8192, bits=1, grey=True))
    return ("python", f"""
import resource, sys
from sinshape.core import budget
from sinshape.core.errors import InputError
budget.available_memory = lambda: 2 << 30
from sinshape.prep.pyramid import load_pyramid
try:
    load_pyramid({str(path)!r}, res=16, levels=1)
    said = "read"
except InputError as error:
    said = str(error)
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
print("HELD" if "needs about" in said and peak < 1 else "FAILED", f"peak {{peak:.1f}} GB:", said[:120])
""")


def one_colour(size):
    def setup(folder):
        path = textured_obj(folder, texture=png(size, size, rgb=(200, 100, 50)))
        return ["train", path, "-o", folder / "out.onnx", *TRAIN]
    return setup


def tinted_gltf(folder):
    return ("python", f"""
import numpy as np, trimesh
from pathlib import Path
mesh = trimesh.load({str(DATA / "colour" / "box_texture.glb")!r}, force="mesh", process=False)
mesh.visual.vertex_attributes["color"] = np.full((len(mesh.vertices), 4), 128, np.uint8)
Path({str(folder / "t.glb")!r}).write_bytes(mesh.export(file_type="glb"))
from sinshape.prep.pyramid import load_pyramid
p = load_pyramid({str(folder / "t.glb")!r}, res=16, levels=1)
z = p.levels[-1].shape[2]
top = p.colours[-1][..., z - 2][:, p.bands[-1][..., z - 2] > 0].mean(axis=1)
plain = load_pyramid({str(DATA / "colour" / "box_texture.glb")!r}, res=16, levels=1)
ptop = plain.colours[-1][..., z - 2][:, plain.bands[-1][..., z - 2] > 0].mean(axis=1)
print("HELD" if top[0] < 0.85 * ptop[0] else "FAILED", "top red", round(float(top[0]), 3), "untinted", round(float(ptop[0]), 3))
""")


def truncated(no_colour):
    def setup(folder):
        good = (DATA / "colour" / "box_texture.png").read_bytes()
        path = textured_obj(folder, texture=good[:len(good) - 30])
        return ["train", path, "-o", folder / "out.onnx", *TRAIN, *(["--no-colour"] if no_colour else [])]
    return setup


def render_texture(folder):
    return ("python", f"""
import subprocess, sys, numpy as np
from PIL import Image
out = {str(folder / "out.png")!r}
subprocess.run([sys.executable, "-c", {SINRUN!r}, "render", {str(DATA / "colour" / "box_texture.glb")!r}, "-o", out,
                "--image-size", "96", "--elevation", "0", "--up", "z"], check=True, capture_output=True)
cell = np.asarray(Image.open(out).convert("RGB"), np.float32)
upper, lower = cell[30:40, 40:56].reshape(-1, 3).mean(0), cell[56:66, 40:56].reshape(-1, 3).mean(0)
print("HELD" if upper[0] > 2 * upper[2] and lower[2] > 2 * lower[0] else "FAILED", upper.round(), lower.round())
""")


def resumed_texture(no_colour):
    def setup(folder):
        path = textured_obj(folder)
        return ("python", f"""
import subprocess, sys
from pathlib import Path
from sinshape.trainer import train
from sinshape.trainer.config import make_config
def stop(p):
    raise KeyboardInterrupt
try:
    train.train({str(path)!r}, {str(folder / "m.onnx")!r}, make_config("tiny", res=16, levels=1, iters=2), progress=stop)
except train.Interrupted:
    pass
if not {no_colour}:
    Path({str(folder / "box_texture.png")!r}).write_bytes({png(4, 8, rgb=(10, 200, 10))!r})  # another texture
result = subprocess.run([sys.executable, "-c", {SINRUN!r}, "train", {str(path)!r}, "-o", {str(folder / "m.onnx")!r},
                         "--resume", *(["--no-colour"] if {no_colour} else [])], capture_output=True, text=True)
lines = [l for l in result.stderr.splitlines() if l.strip()]
held = result.returncode != 0 and len(lines) == 1 and lines[0].startswith("Error:")
print("HELD" if held else "FAILED", result.returncode, (lines or [""])[-1][:150])
""")
    return setup


def job_over(first, second):
    def setup(folder):
        return ("python", f"""
import subprocess, sys
def sinrun(*args):
    return subprocess.run([sys.executable, "-c", {SINRUN!r}, *args], capture_output=True, text=True)
assert sinrun(*{first!r}).returncode == 0
result = sinrun(*{second!r})
lines = [l for l in (result.stdout + result.stderr).splitlines() if l.strip()]
print("HELD" if result.returncode != 0 and len(lines) == 1 and lines[0].startswith("Error:") else "FAILED",
      (lines or [""])[-1][:150])
""")
    return setup


def index_kind(kind):
    def setup(folder):
        index = folder / "outindex.jsonl"  # beside out{seed}.npz
        if kind == "folder":
            index.mkdir()
        elif kind == "fifo":
            os.mkfifo(index)
        else:
            with open(index, "wb") as f:
                f.truncate(6 << 30)
        return ["sample", TINY, "--seeds", "0-1", "-o", folder / "out{seed}.npz", "--workers", "1"]
    return setup


def small_memory_block(folder):
    return ("python", f"""
from sinshape.core import budget
from sinshape.core.errors import InputError
budget.available_memory = lambda: int(2.5 * 2**30)
from sinshape import models
from sinshape.runtime import load_model, write
from sinshape.runtime.request import SampleRequest
model = load_model(models.find("terrain"), threads=2)
tiles = [(i, j) for i in range(64) for j in range(64)]
import threading, time
try:
    write.write_block(model, SampleRequest(3, scale=2), tiles, {str(folder / "out.ply")!r})
    print("FAILED: written")
except (InputError, MemoryError) as error:
    print("HELD" if isinstance(error, InputError) and "needs about" in str(error) else "FAILED", str(error)[:150])
""")


def tile_left(folder):
    return ("python", """
from sinshape import models
from sinshape.runtime import load_model
from sinshape.runtime.request import SampleRequest
from sinshape.serve.jobs import Job, make_sample
from sinshape.serve.sampler import Cancelled
model = load_model(models.find("terrain"), threads=1)
calls = []
def checkpoint(*_):
    calls.append(1)
    raise Cancelled
try:
    make_sample(model, Job("terrain", SampleRequest(1, scale=2, tile=(2, 3)), "ply"), checkpoint)
    print("FAILED: the tile was made to the end; its checkpoint was never asked")
except Cancelled:
    print("HELD: stopped at its first checkpoint")
""")


def overflowing_colour_head(folder):
    return ("python", f"""
import subprocess, sys, numpy as np, onnx
from onnx import numpy_helper
sys.path.insert(0, {str(ROOT / "tests")!r})
from conftest import sealed_bytes
proto = onnx.load({str(DATA / "tiny_colour.onnx")!r})
for weight in proto.graph.initializer:
    if weight.name == "decoder_head.weight_colour":
        values = numpy_helper.to_array(weight)
        signs = np.where(np.arange(values.size).reshape(values.shape) % 2, 1, -1)
        weight.CopyFrom(numpy_helper.from_array((3e38 * signs).astype(np.float32), weight.name))
open({str(folder / "bad.onnx")!r}, "wb").write(sealed_bytes(proto))
result = subprocess.run([sys.executable, "-c", {SINRUN!r}, "sample", {str(folder / "bad.onnx")!r}, "-o",
                         {str(folder / "out.ply")!r}], capture_output=True, text=True)
lines = [l for l in (result.stdout + result.stderr).splitlines() if l.strip()]
print("HELD" if result.returncode != 0 and len(lines) == 1 and lines[0].startswith("Error:") else "FAILED",
      result.returncode, (lines or [""])[-1][:150])
""")


def site_port(port):
    def setup(folder):
        return ("python", f"""
import socket, subprocess, sys
from sinshape.serve import site_server
port = {port!r}
taken = None
if port == "taken":
    taken = socket.socket(); taken.bind(("127.0.0.1", 0)); taken.listen(); port = str(taken.getsockname()[1])
result = subprocess.run([sys.executable, "-I", "-S", site_server.__file__, port], capture_output=True, text=True, timeout=20)
lines = [l for l in (result.stdout + result.stderr).splitlines() if l.strip()]
print("HELD" if result.returncode != 0 and len(lines) == 1 and lines[0].startswith("Error:") else "FAILED",
      (lines or [""])[-1][:120])
""")
    return setup


def site_json(folder):
    return ("python", f"""
import threading, urllib.error, urllib.request
from sinshape.serve import site_server
server = site_server.make_server({str(folder)!r}, 0)
threading.Thread(target=server.serve_forever, daemon=True).start()
try:
    urllib.request.urlopen(f"http://127.0.0.1:{{server.server_address[1]}}/nothing.js", timeout=10)
except urllib.error.HTTPError as error:
    kind = error.headers["Content-Type"]
    print("HELD" if kind == "application/json" else "FAILED", error.code, kind)
server.shutdown()
""")


def checkpoint_limit(folder):
    return ("python", f"""
import resource, signal, sys
sys.path.insert(0, {str(ROOT / "tests")!r})
from conftest import write_pyramid
from sinshape.trainer import train
from sinshape.trainer.config import make_config
pyramid = write_pyramid({str(folder / "t.h5")!r}, [(15, 15, 15), (20, 18, 15)])
checkpoint = train.default_checkpoint_path({str(folder / "m.onnx")!r})
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
kept = []
def progress(p):
    if p.level == 1 and not kept:
        kept.append(checkpoint.read_bytes())
        resource.setrlimit(resource.RLIMIT_FSIZE, (len(kept[0]) + 1000, resource.RLIM_INFINITY))
try:
    train.train(pyramid, {str(folder / "m.onnx")!r}, make_config("tiny", iters=2), progress=progress)
    print("FAILED: trained")
except Exception as error:
    from sinshape.core.errors import InputError
    one = isinstance(error, InputError) and checkpoint.read_bytes() == kept[0]
    print("HELD" if one else "FAILED", type(error).__name__, str(error).splitlines()[0][:150])
""")


def gltf(change):
    return lambda meta, outside: change(meta, outside)


PBR = lambda meta: meta["materials"][0]["pbrMetallicRoughness"]  # noqa: E731
CASES = [
    # 1. every file a mesh names is read from its own folder, and no read blocks
    ("1. files a mesh names", "map_Kd an absolute path to an image outside", mtl_case("map_Kd {outside}/secret.png"), "error:outside"),
    ("1. files a mesh names", "map_Kd ../secret.png", mtl_case("map_Kd ../secret.png"), "error:outside"),
    ("1. files a mesh names", "map_Kd /etc/passwd", mtl_case("map_Kd /etc/passwd"), "error:outside"),
    ("1. files a mesh names", "map_Kd /proc/self/environ", mtl_case("map_Kd /proc/self/environ"), "error:outside"),
    ("1. files a mesh names", "map_Kd /etc/shadow", mtl_case("map_Kd /etc/shadow"), "error:outside"),
    ("1. files a mesh names", "mtllib /etc/passwd", obj_library("/etc/passwd"), "error:outside"),
    ("1. files a mesh names", "mtllib ../x.mtl", obj_library("../x.mtl"), "error:outside"),
    ("1. files a mesh names", "glTF image uri /etc/passwd", gltf_case(lambda m, o: m["images"][0].update(uri="/etc/passwd")), "error:outside"),
    ("1. files a mesh names", "glTF image uri ../secret.png", gltf_case(lambda m, o: m["images"][0].update(uri="../secret.png")), "error:outside"),
    ("1. files a mesh names", "glTF image uri absolute, outside", gltf_case(lambda m, o: m["images"][0].update(uri=str(o / "secret.png"))), "error:outside"),
    ("1. files a mesh names", "glTF buffer uri /etc/passwd", gltf_case(lambda m, o: m["buffers"][0].update(uri="/etc/passwd")), "error:outside"),
    ("1. files a mesh names", "glTF buffer uri ../box.bin", gltf_case(lambda m, o: m["buffers"][0].update(uri="../box.bin")), "error:outside"),
    ("1. files a mesh names", "a texture linked from outside", linked_out, "error:outside"),
    ("1. files a mesh names", "a FIFO as the texture: train", fifo_in(textured_obj, "box_texture.png"), "refused"),
    ("1. files a mesh names", "a FIFO as the MTL: train", fifo_in(textured_obj, "box_texture.mtl"), "refused"),
    ("1. files a mesh names", "a FIFO as the glTF buffer: train", fifo_in(textured_gltf, "box.bin"), "refused"),
    ("1. files a mesh names", "a FIFO as the glTF image: train", fifo_in(textured_gltf, "tex.png"), "refused"),
    ("1. files a mesh names", "a FIFO as the texture: render", fifo_in(textured_obj, "box_texture.png", "render"), "ok:FIFO"),
    ("1. files a mesh names", "a FIFO as the glTF buffer: render", fifo_in(textured_gltf, "box.bin", "render"), "refused"),
    ("1. files a mesh names", "a FIFO as the MTL: sample --layout", fifo_in(textured_obj, "box_texture.mtl", "layout"), "ok:wrote"),
    ("1. files a mesh names", "a folder as the texture", texture_folder, "refused"),
    # 2. glTF structure and image sizes
    ("2. glTF structure, image sizes", "texture index out of range", gltf_case(lambda m, o: PBR(m)["baseColorTexture"].update(index=5)), "refused"),
    ("2. glTF structure, image sizes", "image index out of range", gltf_case(lambda m, o: m["textures"][0].update(source=3)), "refused"),
    ("2. glTF structure, image sizes", "an empty image list", gltf_case(lambda m, o: m.update(images=[])), "refused"),
    ("2. glTF structure, image sizes", "a string where an index belongs", gltf_case(lambda m, o: m["textures"][0].update(source="0")), "refused"),
    ("2. glTF structure, image sizes", "a data: URI without a comma", gltf_case(lambda m, o: m["images"][0].update(uri="data:image/png;base64")), "refused"),
    ("2. glTF structure, image sizes", "a data: URI of bad base64", gltf_case(lambda m, o: m["images"][0].update(uri="data:image/png;base64,@@@@")), "refused"),
    ("2. glTF structure, image sizes", "a buffer of bad base64", gltf_case(lambda m, o: m["buffers"][0].update(uri="data:application/octet-stream;base64,x")), "refused"),
    ("2. glTF structure, image sizes", "a NaN baseColorFactor", gltf_case(lambda m, o: PBR(m).update(baseColorFactor=[float("nan"), 1, 1, 1])), "refused"),
    ("2. glTF structure, image sizes", "a baseColorFactor of 300", gltf_case(lambda m, o: PBR(m).update(baseColorFactor=[300, 1, 1, 1])), "refused"),
    ("2. glTF structure, image sizes", "a buffer view past its buffer", gltf_case(lambda m, o: m["bufferViews"][2].update(byteLength=10**9)), "refused"),
    ("2. glTF structure, image sizes", "a material index out of range", gltf_case(lambda m, o: m["meshes"][0]["primitives"][0].update(material=7)), "refused"),
    ("2. glTF structure, image sizes", "a 16 kB 1-bit PNG of 16384x8192, 2 GiB free", pixel_bomb, "python"),
    ("2. glTF structure, image sizes", "a texture padded to 6 GiB", padded_texture, "refused"),
    ("2. glTF structure, image sizes", "UVs of 3e38", huge_uvs, "refused"),
    ("2. glTF structure, image sizes", "an MTL Kd of NaN", mtl_case("map_Kd box_texture.png\nKd nan nan nan"), "refused"),
    ("2. glTF structure, image sizes", "map_Kd -s 1 1 1 box_texture.png (valid)", mtl_case("map_Kd -s 1 1 1 box_texture.png"), "ok:coloured"),
    ("2. glTF structure, image sizes", "map_Kd -clamp on -o 0 0 box_texture.png (valid)", mtl_case("map_Kd -clamp on -o 0 0 box_texture.png"), "ok:coloured"),
    # colour input a user would be surprised by
    ("honest colour input", "training says which colour it read", mtl_case("map_Kd box_texture.png"), "ok:colour: texture box_texture.png (4x8)"),
    ("honest colour input", "glTF vertex colours beside a texture are multiplied", tinted_gltf, "python"),
    ("honest colour input", "a 1x1 texture is warned about", one_colour(1), "ok:is one colour"),
    ("honest colour input", "a one-colour texture is warned about", one_colour(8), "ok:is one colour"),
    ("honest colour input", "a truncated texture is named", truncated(False), "error:texture box_texture.png: cannot read it as an image"),
    ("honest colour input", "--no-colour gets past a truncated texture", truncated(True), "ok:wrote"),
    ("honest colour input", "render draws a textured example in its texture", render_texture, "python"),
    # 3. a resume checks it is the job its index records
    ("3. resumes of another job", "world seed 5 into seed 0's folder", job_over(
        ["world", str(TINY), "--seed", "0", "--tiles", "0,0:1", "-o", "{f}/w", "--workers", "1"],
        ["world", str(TINY), "--seed", "5", "--tiles", "0,0:1", "-o", "{f}/w", "--workers", "1"]), "python"),
    ("3. resumes of another job", "terrain's world into another model's folder", job_over(
        ["world", str(TINY), "--tiles", "0,0:1", "-o", "{f}/w", "--workers", "1"],
        ["world", "terrain", "--tiles", "0,0:1", "-o", "{f}/w", "--workers", "1"]), "python"),
    ("3. resumes of another job", "--seeds --scale 2 over a --scale 1 job", job_over(
        ["sample", str(TINY), "--seeds", "0-1", "-o", "{f}/{seed}.npz", "--workers", "1"],
        ["sample", str(TINY), "--seeds", "0-1", "--scale", "2", "-o", "{f}/{seed}.npz", "--workers", "1"]), "python"),
    ("3. resumes of another job", "a training resume after the texture changed", resumed_texture(False), "python"),
    ("3. resumes of another job", "a training resume with --no-colour on a coloured checkpoint", resumed_texture(True), "python"),
    # 4. world jobs and the tile route bounded
    ("4. world bounds, indexes, tile slots", "a block of 100000 x 100000 tiles", lambda f: ["world", "terrain", "--tiles", "0:99999,0:99999", "-o", f / "out.ply"], "refused"),
    ("4. world bounds, indexes, tile slots", "4096 tiles at scale 2 under 2.5 GiB", small_memory_block, "python"),
    ("4. world bounds, indexes, tile slots", "a tile range whose length overflows", lambda f: ["world", "terrain", "--tiles", f"{-(2**62) + 1}:{2**62 - 1},{-(2**62) + 1}:{2**62 - 1}", "-o", f / "out"], "refused"),
    ("4. world bounds, indexes, tile slots", "an index that is a folder", index_kind("folder"), "refused"),
    ("4. world bounds, indexes, tile slots", "an index that is a FIFO", index_kind("fifo"), "refused"),
    ("4. world bounds, indexes, tile slots", "an index that is a 6 GiB sparse file", index_kind("sparse"), "refused"),
    ("4. world bounds, indexes, tile slots", "a slow tile its client left", tile_left, "python"),
    # 5. (the colour head's half)
    ("5. a colour head that overflows", "colour weights of +-3e38, sealed", overflowing_colour_head, "python"),
    # 6. still open from last time
    ("6. serve.py, checkpoints", "serve.py's 404", site_json, "python"),
    ("6. serve.py, checkpoints", "serve.py http (not a number)", site_port("http"), "python"),
    ("6. serve.py, checkpoints", "serve.py 70000 (out of range)", site_port("70000"), "python"),
    ("6. serve.py, checkpoints", "serve.py on a taken port", site_port("taken"), "python"),
    ("6. serve.py, checkpoints", "a checkpoint under a file-size limit", checkpoint_limit, "python"),
    # 7. every file a user names is looked at before a byte of it is read (the fifth probe)
    ("7. files looked at first", "a FIFO as a .npy height map", special_map("fifo", ".npy", "--map"), "refused"),
    ("7. files looked at first", "a FIFO as a .png height map", special_map("fifo", ".png", "--map"), "refused"),
    ("7. files looked at first", "a FIFO as the model map", special_map("fifo", ".png", "--models-map"), "refused"),
    ("7. files looked at first", "/dev/zero as the height map", special_map("device", "", "--map"), "refused"),
    ("7. files looked at first", "a link to /dev/zero as the height map", special_map("link", ".npy", "--map"), "refused"),
    ("7. files looked at first", "/dev/zero as the model map", special_map("device", "", "--models-map"), "refused"),
    ("7. files looked at first", "a FIFO as the model", lambda f: (fifo(f / "m.onnx"), ["sample", f / "m.onnx", "-o", f / "out.ply"])[1], "refused"),
    ("7. files looked at first", "a FIFO as the layout", lambda f: (fifo(f / "l.npz"), ["sample", "terrain", "--layout", f / "l.npz", "-o", f / "out.ply"])[1], "refused"),
    ("7. files looked at first", "a 2 GiB sparse map, under 200 MB of memory", sparse_map, "python"),
    # 8. uploads refused before they are held
    ("8. uploads bounded", "a declared 400 MB layout", upload("/api/models/terrain/sample?seed=1", "declared"), "python"),
    ("8. uploads bounded", "a declared 400 MB height map", upload("/api/models/terrain/tile?i=0&j=0", "declared"), "python"),
    ("8. uploads bounded", "a chunked 5 MB height map", upload("/api/models/terrain/tile?i=0&j=0", "chunked"), "python"),
    # 9. a weight twice
    ("9. one weight of each name", "colour_tiles.images twice, resealed", doubled_weight, "refused"),
    # 10. messages that name fields
    ("10. messages as typed", "NaN in a .npy height map", nan_map, "error:a height map holds values in voxels"),
    ("10. messages as typed", "256 models after the first", many_models, "error:a world takes at most 255 MODEL..."),
    # 11. signals at stated points, output folders
    ("11. signals, folders", "Ctrl-C as eval imports onnxruntime", stopped_at("import:onnxruntime", "INT", ["eval", "terrain", "-n", "2", "--reference", "{f}/box.obj"]), "python"),
    ("11. signals, folders", "SIGTERM as sample writes, then Ctrl-C", stopped_at("c_call:fsync", "TERM+INT", ["sample", "terrain", "-o", "{f}/out.ply"]), "python"),
    ("11. signals, folders", "--seeds with -o job/{seed}.glb makes job", lambda f: ["sample", "terrain", "--seeds", "0-1", "--lods", "200", "-o", f / "job" / "{seed}.glb"], "ok:wrote"),
]


def run_case(setup, expect, python: str) -> tuple:
    """(held, what happened) of one case, in a fresh folder."""
    with tempfile.TemporaryDirectory() as root:
        folder = Path(root) / "mesh"
        folder.mkdir()
        made = setup(folder)
        there = set(folder.rglob("out*"))
        if isinstance(made, tuple):
            code = made[1].replace("{f}", str(folder))
            argv = [python, "-c", code]
        else:
            argv = [python, "-c", SINRUN, *[str(a).replace("{f}", str(folder)) for a in made]]
        try:
            result = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT, cwd=folder)
        except subprocess.TimeoutExpired:
            return False, f"still running after {TIMEOUT} s"
        output = (result.stdout + result.stderr).strip()
        lines = [line for line in output.splitlines() if line.strip()]
        last = lines[-1][:160] if lines else ""
        if expect == "python":  # its verdict, whatever a server logged after it
            verdicts = [line for line in lines if line.startswith(("HELD", "FAILED"))]
            return bool(verdicts) and verdicts[-1].startswith("HELD"), (verdicts or [last])[-1][:160]
        errors = [line for line in lines if line.startswith("Error:")]
        if expect == "refused":
            written = set(folder.rglob("out*")) - there
            one = result.returncode != 0 and "Traceback" not in output and len(errors) == 1 and not written
            return one and len([line for line in lines if not line.startswith(("Warning:", "warning:"))]) == 1, last
        kind, _, text = expect.partition(":")
        if kind == "error":
            return result.returncode != 0 and "Traceback" not in output and len(errors) == 1 and text in errors[0], last
        return result.returncode == 0 and text in output, last


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--python", default=sys.executable, help="The Python to run the cases with.")
    parser.add_argument("-k", default="", help="Only the cases whose class or name holds this.")
    options = parser.parse_args()
    classes, failed = {}, []
    for kind, name, setup, expect in CASES:
        if options.k not in f"{kind}: {name}":
            continue
        held, said = run_case(setup, expect, options.python)
        counts = classes.setdefault(kind, [0, 0])
        counts[0] += 1
        counts[1] += held
        print(f"{'held ' if held else 'FAILS'} {kind}: {name}: {said}", file=sys.stderr, flush=True)
        if not held:
            failed.append(f"{kind}: {name}")
    print("| class | cases | held |")
    print("|---|---|---|")
    for kind, (count, held) in classes.items():
        print(f"| {kind} | {count} | {held} |")
    total = [sum(c[i] for c in classes.values()) for i in (0, 1)]
    print(f"| all | {total[0]} | {total[1]} |")
    if failed:
        print("failed:", "; ".join(failed))


if __name__ == "__main__":
    main()
