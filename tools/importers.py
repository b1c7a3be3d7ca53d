"""The importers a game asset is checked in, each driven from Python: the
Khronos glTF-Validator and Babylon.js's glTF loader (node, their npm
packages under NODE_MODULES) and Godot 3's headless editor (godot3-server).
tests/test_asset.py and `benchmarks/asset.py engines` both call them, so
that what the tests hold and what the figures say come from one reading.
Each returns None where its tool is not installed.
"""

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

TOOLS = Path(__file__).resolve().parent
# Where .ci/run installs the validator and Babylon.js (npm install --prefix tools/node ...).
NODE_MODULES = Path(os.environ.get("GLTF_VALIDATOR_MODULES", TOOLS / "node" / "node_modules"))


def node_result(script: Path, glb: Path, package: str) -> str | None:
    """A node script's output on a .glb, its packages found under NODE_MODULES (None: not installed)."""
    if not (shutil.which("node") and (NODE_MODULES / package).is_dir()):
        return None
    done = subprocess.run(["node", str(script), str(glb)], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "NODE_PATH": str(NODE_MODULES)})
    if done.returncode:
        raise RuntimeError(f"{script.name} failed on {glb}: {done.stderr.strip()}")
    return done.stdout


def validator_report(glb: Path) -> dict | None:
    """The Khronos glTF-Validator's report on a file."""
    out = node_result(TOOLS / "validate_gltf.mjs", glb, "gltf-validator")
    return None if out is None else json.loads(out)


def result_line(out: str) -> dict:
    """The JSON a driver script prints after `RESULT `."""
    return json.loads(next(line[7:] for line in out.splitlines() if line.startswith("RESULT ")))


def babylon_scene(glb: Path) -> dict | None:
    """What Babylon.js makes of an asset: its glTF loader in a NullEngine
    (babylon/list_meshes.js): {"extensions": [...], "meshes": [...]} once every level is loaded."""
    out = node_result(TOOLS / "babylon" / "list_meshes.js", glb, "babylonjs-loaders")
    return None if out is None else result_line(out)


def godot_scene(glb: Path, folder: Path) -> dict | None:
    """What Godot 3 makes of an asset: its editor's own glTF import
    (headless, in a project made under `folder`), then the scene loaded by
    godot/list_meshes.gd: {"meshes": [...], "collision": [...]}."""
    if not shutil.which("godot3-server"):
        return None
    project = folder / glb.stem
    project.mkdir(parents=True)
    shutil.copy(glb, project / glb.name)
    (project / "project.godot").write_text("config_version=4\n")
    # The editor imports the file, then stays open (Godot 3.2 headless, --quit or not): it is stopped once the
    # import is written, its .md5 record last (after the scene and the .import file).
    editor = subprocess.Popen(["godot3-server", "--path", str(project), "--editor", "--quit"],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def imported() -> bool:
        return any("dest_md5" in record.read_text() for record in project.glob(f".import/{glb.name}-*.md5"))
    try:
        for _ in range(1200):
            if editor.poll() is not None or imported():
                break
            time.sleep(0.1)
    finally:
        editor.kill()
        editor.wait()
    done = subprocess.run(["godot3-server", "--path", str(project), "-s", str(TOOLS / "godot" / "list_meshes.gd"),
                           f"res://{glb.name}"], capture_output=True, text=True, timeout=300)
    return result_line(done.stdout)
