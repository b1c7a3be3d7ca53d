"""The Blender extension across processes: a saved .blend reopened in a new
Blender makes the same meshes (and says which model file went missing or
changed), and the zip tools/build_blender.py builds installs with
Blender's own extension installer and samples from its bundled wheels.
Marked `blender`, skipped where bpy cannot be imported."""

import importlib.util
import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sinshape.runtime import load, world_maps
from test_blender import HAS_BPY, ROOT, add

pytestmark = [pytest.mark.blender,
              pytest.mark.skipif(not HAS_BPY, reason="needs bpy, Blender as a Python module: "
                                                     "pip install 'sinshape[blender]' (Python 3.11)")]

REOPEN = """
import json, sys
import numpy as np
sys.path.insert(0, {root!r})
import bpy, blender
from blender import convert
blender.register()
bpy.ops.wm.open_mainfile(filepath={blend!r})
out = {{}}
for obj in bpy.data.objects:
    if not obj.sinshape.active:
        continue
    error_on_open = obj.sinshape.error
    before = convert.mesh_arrays(obj.data)
    for other in bpy.data.objects:
        other.select_set(other == obj)
    bpy.context.view_layer.objects.active = obj
    try:
        bpy.ops.sinshape.regenerate()
        report = ""
    except RuntimeError as error:
        report = str(error)
    after = convert.mesh_arrays(obj.data)
    out[obj.name] = dict(error_on_open=error_on_open, report=report, error=obj.sinshape.error,
                         vertices=len(after[0]), same=bool(np.array_equal(before[0], after[0])
                                                           and np.array_equal(before[1], after[1])))
print("RESULT" + json.dumps(out))
"""


def test_a_saved_file_reopens_in_a_new_blender_and_makes_the_same_meshes(scene, tiny_model, tmp_path):
    import bpy

    kept, changed, missing = (tmp_path / f"{name}.onnx" for name in ("kept", "changed", "missing"))
    for path in (kept, changed, missing):
        shutil.copyfile(tiny_model, path)
    made = {"shipped": add("terrain", seed=3, scale=2)}
    for path in (kept, changed, missing):
        made[path.stem] = add(path, seed=5, size=(1.25, 1, 1))
    for name, obj in made.items():
        obj.name = name
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    counts = {name: len(obj.data.vertices) for name, obj in made.items()}
    shutil.copyfile(ROOT / "models" / "terrain.onnx", changed)  # another model under the same name
    missing.unlink()

    script = REOPEN.format(root=str(ROOT), blend=str(tmp_path / "scene.blend"))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    result = json.loads(done.stdout.split("RESULT", 1)[1])
    for name in ("shipped", "kept"):  # by name, and by path with its SHA-256 unchanged
        assert result[name] == dict(error_on_open="", report="", error="", vertices=counts[name], same=True)
    assert "has changed since" in result["changed"]["error_on_open"]  # said on the object as the file opens
    assert "is missing" in result["missing"]["error_on_open"]
    for name in ("changed", "missing"):  # reported, never silently replaced: the mesh is as it was saved
        assert result[name]["report"] and result[name]["error"] in result[name]["report"]
        assert result[name]["same"] and result[name]["vertices"] == counts[name]


INSTALL = """
import sys, json
sys.path.insert(0, {path!r})
import bpy
bpy.ops.extensions.package_install_files(filepath={zip!r}, repo="user_default", enable_on_install=True)
import sinshape, onnxruntime, trimesh, PIL
from sinshape import models
from sinshape.runtime import generate, load, mesh, world_maps
bpy.ops.sinshape.add_sample(model="towerruins", seed=3)
obj = bpy.context.active_object
model = load.load_model(models.find("towerruins"))
expected = mesh.extract(model, generate.sample(model, 3))
heights = world_maps.read_height_map({heights!r}, model).array()  # a .png map: Blender's Python has no pillow
placed = world_maps.read_model_map({placed!r}).array()
print("RESULT" + json.dumps(dict(modules=[m.__file__ or str(list(m.__path__)) for m in (sinshape, onnxruntime, trimesh, PIL)],
                                 vertices=len(obj.data.vertices), expected=len(expected.vertices),
                                 faces=len(obj.data.polygons), expected_faces=len(expected.faces),
                                 heights=heights.tolist(), placed=placed.tolist())))
"""


def test_the_built_zip_installs_in_blender_and_samples_from_its_own_wheels(tmp_path):
    """Offline: this platform's zip from the installed packages, installed
    by Blender's own installer into a Blender that sees nothing of this
    environment but bpy and numpy (which Blender ships)."""
    spec = importlib.util.spec_from_file_location("build_blender", ROOT / "tools" / "build_blender.py")
    build = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build)
    out = build.build(tmp_path / "sinshape.zip", [build.this_platform()], offline=True)
    with zipfile.ZipFile(out) as archive:
        names = archive.namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert sorted(n.split("/")[1].split("-")[0] for n in names if n.startswith("wheels/")) == sorted(
        ["sinshape", *build.BUNDLED])
    bpy_folder = Path(importlib.util.find_spec("bpy").submodule_search_locations[0])
    checker = bpy_folder / "5.0" / "scripts" / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    checked = subprocess.run([sys.executable, str(checker), "validate", str(out)], capture_output=True, text=True)
    assert checked.returncode == 0, checked.stdout + checked.stderr

    only = tmp_path / "path"  # bpy and numpy alone: the rest must come from the zip
    only.mkdir()
    for name in ("bpy", "numpy"):
        (only / name).symlink_to(Path(importlib.util.find_spec(name).submodule_search_locations[0]))
    home = tmp_path / "home"  # nothing may be written there (onnxruntime's telemetry was)
    home.mkdir()
    env = {"BLENDER_USER_RESOURCES": str(tmp_path / "user"), "PATH": "/usr/bin:/bin", "HOME": str(home)}
    grey = np.array([[0, 255, 128], [64, 32, 16]], np.uint8)  # rows from the top, as an image holds them
    Image.fromarray(grey).save(tmp_path / "hills.png")
    Image.fromarray(np.array([[0, 1], [1, 0]], np.uint8)).save(tmp_path / "placed.png")
    script = INSTALL.format(path=str(only), zip=str(out), heights=str(tmp_path / "hills.png"),
                            placed=str(tmp_path / "placed.png"))
    done = subprocess.run([sys.executable, "-I", "-S", "-c", script], capture_output=True, text=True, timeout=600,
                          env=env)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    result = json.loads(done.stdout.split("RESULT", 1)[1])
    extensions = str(tmp_path / "user" / "extensions")
    assert all(extensions in module for module in result["modules"])
    assert result["vertices"] == result["expected"] > 0 and result["faces"] == result["expected_faces"]
    tower = load.load_model(ROOT / "models" / "towerruins.onnx", threads=1)  # the maps, as read outside Blender
    assert np.allclose(result["heights"], world_maps.read_height_map(tmp_path / "hills.png", tower).array())
    assert result["placed"] == world_maps.read_model_map(tmp_path / "placed.png").array().tolist()
    written = [str(p.relative_to(home)) for p in home.rglob("*") if p.is_file()]
    assert written == [], written


SCRIPT = """
import sys
sys.path.insert(0, {root!r})
import bpy, blender
blender.register()
bpy.ops.sinshape.add_sample(model={model!r}, seed=1)
bpy.ops.sinshape.variations(count=2, first_seed=5)
print("MADE", sorted(o.sinshape.seed for o in bpy.data.objects if o.sinshape.active))
"""


def test_variations_start_their_workers_from_a_script_that_imports_bpy(tmp_path, tiny_model):
    """Worker processes re-import __main__ when they start; where that is a
    script importing bpy (`blender --python`, here a file run by Python) they
    must not, or each would die as it starts, and be started again."""
    script = tmp_path / "script.py"
    script.write_text(SCRIPT.format(root=str(ROOT), model=str(tiny_model)))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "MADE [1, 5, 6]" in done.stdout
