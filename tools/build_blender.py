"""Build the Blender extension from the checkout: one zip to install with
Blender's Preferences > Get Extensions > Install from Disk.

    python tools/build_blender.py -o sinshape-blender.zip                        # every platform with wheels
    python tools/build_blender.py -o sinshape-linux.zip --platform linux-x64
    python tools/build_blender.py -o sinshape-linux.zip --platform linux-x64 --offline

The zip holds blender/ (the add-on and its manifest, filled in here) and the
wheels the add-on imports, so that Blender downloads nothing: sinshape's own,
built from the checkout (pip wheel --no-deps .), and those of the runtime's
dependencies that Blender lacks (BUNDLED: onnxruntime and pillow per
platform, trimesh, threadpoolctl; Blender ships numpy; pillow reads a
world's .png height and model maps). They are fetched with `pip download` for
each platform (this needs the network once) into a cache folder, reused
after. --offline needs no network: it builds for this machine's platform
only, from this environment's installed packages, each packed back into a
wheel as installed.
"""

import argparse
import base64
import csv
import hashlib
import importlib.metadata
import io
import platform
import re
import string
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ADDON = ROOT / "blender"
BLENDER_PYTHON = "3.11"  # Blender 4.2 to 5.x
BUNDLED = ("onnxruntime", "trimesh", "threadpoolctl", "pillow")  # the runtime's dependencies the add-on imports, less numpy
# Blender's platforms and pip's tags for each: glibc 2.28 and macOS 11, the
# oldest systems Blender 4.2 runs on. Linux on ARM has no Blender release.
PLATFORMS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "windows-x64": ["win_amd64"],
    "windows-arm64": ["win_arm64"],
    "macos-arm64": ["macosx_11_0_arm64"],
    "macos-x64": ["macosx_11_0_x86_64"],
}
CACHE = Path.home() / ".cache" / "sinshape" / "blender-wheels"


def requirements() -> list:
    """pyproject.toml's requirements of the BUNDLED packages, as written there."""
    dependencies = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return [d for d in dependencies if re.match(r"[\w.-]+", d)[0].lower() in BUNDLED]


def version() -> str:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]


def this_platform() -> str:
    """This machine as Blender names platforms (linux-x64, macos-arm64, ...)."""
    system = {"darwin": "macos"}.get(platform.system().lower(), platform.system().lower())
    machine = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64"}.get(platform.machine().lower(),
                                                                       platform.machine().lower())
    return f"{system}-{machine}"


def pip(*args) -> None:
    done = subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"pip {args[0]} failed:\n{done.stdout[-2000:]}{done.stderr[-2000:]}")


def sinshape_wheel(folder: Path, offline: bool) -> Path:
    """sinshape's wheel, built from the checkout (offline: with this environment's setuptools)."""
    pip("wheel", "--no-deps", "--quiet", *(["--no-build-isolation"] if offline else []), "-w", str(folder), str(ROOT))
    (wheel,) = folder.glob("sinshape-*.whl")
    return wheel


def downloaded_wheels(blender_platform: str, cache: Path) -> list:
    """The BUNDLED wheels for a platform, from the cache, downloaded there once."""
    folder = cache / blender_platform
    names = [re.match(r"[\w.-]+", r)[0].lower().replace("-", "_") for r in requirements()]
    found = lambda: {name: sorted(folder.glob(f"{name}-*.whl"), key=lambda w: w.stat().st_mtime)  # noqa: E731
                     for name in names}
    if not all(found().values()):
        tags = [arg for tag in PLATFORMS[blender_platform] for arg in ("--platform", tag)]
        pip("download", "--quiet", "--no-deps", "--only-binary=:all:", "--python-version", BLENDER_PYTHON,
            "--implementation", "cp", *tags, "-d", str(folder), *requirements())
    return [wheels[-1] for wheels in found().values()]


def installed_wheel(name: str, folder: Path) -> Path:
    """An installed distribution packed back into the wheel it was installed
    from (its files as RECORD lists them, less what the installer added)."""
    dist = importlib.metadata.distribution(name)
    info = Path(dist.locate_file(next(f for f in dist.files if f.match("*.dist-info/WHEEL")))).parent
    tags = [line.split(":", 1)[1].strip() for line in (info / "WHEEL").read_text().splitlines()
            if line.startswith("Tag:")]
    tag = "-".join(".".join(sorted({t.split("-")[k] for t in tags})) for k in range(3))
    wheel = folder / f"{info.name.removesuffix('.dist-info')}-{tag}.whl"
    skipped = {f"{info.name}/{n}" for n in ("INSTALLER", "REQUESTED", "direct_url.json", "RECORD")}
    records = io.StringIO()
    rows = csv.writer(records, lineterminator="\n")
    with zipfile.ZipFile(wheel, "w", zipfile.ZIP_DEFLATED) as archive:
        for file in dist.files:
            path = str(file).replace("\\", "/")
            if path.startswith("../") or "__pycache__/" in path or path in skipped:
                continue
            data = Path(dist.locate_file(file)).read_bytes()
            archive.writestr(path, data)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            rows.writerow([path, f"sha256={digest}", len(data)])
        rows.writerow([f"{info.name}/RECORD", "", ""])
        archive.writestr(f"{info.name}/RECORD", records.getvalue())
    return wheel


def manifest(platforms: list, wheels: list) -> str:
    template = string.Template((ADDON / "blender_manifest.toml").read_text())
    listing = lambda items: "[\n" + "".join(f'  "{item}",\n' for item in items) + "]"  # noqa: E731
    return template.substitute(version=version(), platforms=listing(platforms),
                               wheels=listing(f"./wheels/{w.name}" for w in wheels))


def build(output: Path, platforms: list, cache: Path = CACHE, offline: bool = False) -> Path:
    """Write the extension zip for `platforms` (Blender's names); offline:
    this machine's platform only, from the installed packages."""
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown:
        raise SystemExit(f"unknown platform {', '.join(unknown)}; choose from {', '.join(PLATFORMS)}")
    if offline and platforms != [this_platform()]:
        raise SystemExit(f"--offline builds for this machine's platform alone: --platform {this_platform()}")
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        wheels = [sinshape_wheel(scratch, offline)]
        if offline:
            wheels += [installed_wheel(name, scratch) for name in BUNDLED]
        else:
            wheels += {w.name: w for p in platforms for w in downloaded_wheels(p, cache)}.values()  # each once
        partial = output.with_name(output.name + ".partial")
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as archive:
            for source in sorted(ADDON.glob("*.py")):
                archive.write(source, source.name)
            archive.writestr("blender_manifest.toml", manifest(platforms, wheels))
            for wheel in wheels:
                archive.write(wheel, f"wheels/{wheel.name}", zipfile.ZIP_STORED)  # a wheel is compressed already
        partial.replace(output)
    return output


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("sinshape-blender.zip"))
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORMS),
                        help="Blender's name of a platform to bundle wheels for; repeat for more (default: all)")
    parser.add_argument("--cache", type=Path, default=CACHE, help="Where downloaded wheels are kept")
    parser.add_argument("--offline", action="store_true",
                        help="No network: this machine's platform, from the installed packages")
    args = parser.parse_args(argv)
    platforms = args.platform or ([this_platform()] if args.offline else list(PLATFORMS))
    out = build(args.output, platforms, args.cache, args.offline)
    print(f"wrote {out} ({out.stat().st_size / 2**20:.1f} MB; {', '.join(platforms)})")


if __name__ == "__main__":
    main()
