"""Peak memory of `sinrun serve` while it refuses hostile layout uploads of
at most 2 kB: how far above its idle memory each one takes the service.

Each body describes as large a layout as 2 kB can: bzip2 packs a GB of
zeros in under a kB, a header may declare any shape, a .vox any size and
count. The service runs in a child process; its peak resident memory
(VmHWM, reset before each upload through /proc/PID/clear_refs) less its
resident memory when idle is what the upload cost.

    python benchmarks/hostile_upload.py                      # this checkout
    python benchmarks/hostile_upload.py --python OTHER/.venv/bin/python   # another install, e.g. before a change

Linux only (/proc). Prints one row per body.
"""

import argparse
import contextlib
import io
import json
import socket
import struct
import subprocess
import sys
import time
import urllib.error
import urllib.request
import zipfile
from pathlib import Path

import numpy as np

LIMIT = 2048  # bytes of a body


def npy_header(shape, descr="|b1") -> bytes:
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(out, {"descr": descr, "fortran_order": False, "shape": shape})
    return out.getvalue()


def npz(members: list) -> bytes:
    """An archive of (name, header, zero count, compression) members."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        for name, header, count, method in members:
            compression = zipfile.ZIP_BZIP2 if method == "bzip2" else zipfile.ZIP_DEFLATED
            archive.writestr(zipfile.ZipInfo(name), header + bytes(count), compress_type=compression,
                             compresslevel=9)
    return out.getvalue()


def vox(size, count) -> bytes:
    body = b"SIZE" + struct.pack("<2i3i", 12, 0, *size) + b"XYZI" + struct.pack("<2ii", 4 + 4 * 200, 0, count)
    body += bytes(4 * 200)
    return b"VOX " + struct.pack("<i", 150) + b"MAIN" + struct.pack("<2i", 0, len(body)) + body


def bodies() -> dict:
    side = 800  # 512 MB of cells: built in this process's memory, once
    return {
        "npz: 'layout' beside 'layout.npy' (512 MB bzip2)": npz([
            ("layout.npy", npy_header((4, 4, 4)), 64, "deflate"),
            ("layout", npy_header((side, side, side)), side**3, "bzip2")]),
        "npz: layout.npy of 512^3 cells (128 MB bzip2)": npz([("layout.npy", npy_header((512, 512, 512)), 512**3,
                                                               "bzip2")]),
        "npz: header of 512^3 floats (1 GB), deflate data": npz([("layout.npy", npy_header((512, 512, 512), "<f8"),
                                                                  1 << 20, "deflate")]),
        "npz: layout.npy of 120^3 cells, deflate (1.7 MB)": npz([("layout.npy", npy_header((120, 120, 120)), 120**3,
                                                                  "deflate")]),
        "vox: 256^3, 2**31-1 voxels claimed": vox((256, 256, 256), 2**31 - 1),
    }


def status_mb(pid: int, field: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {field}")


def post(url: str, body: bytes) -> tuple:
    request = urllib.request.Request(url, data=body, method="POST", headers={"Content-Type": "application/octet-stream"})
    try:
        with urllib.request.urlopen(request, timeout=600) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


@contextlib.contextmanager
def service(python: str):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = "from sinshape.cli.main import main; main()"
    process = subprocess.Popen([python, "-c", code, "serve", "terrain", "--threads", "2", "--port", str(port)],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            with contextlib.suppress(OSError):
                if urllib.request.urlopen(f"{base}/health", timeout=5).status == 200:
                    break
            time.sleep(0.1)
        yield base, process.pid
    finally:
        process.terminate()
        process.wait(timeout=30)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--python", default=sys.executable, help="the interpreter whose sinshape serves")
    args = parser.parse_args()
    made = bodies()
    with service(args.python) as (base, pid):
        url = f"{base}/api/models/terrain/sample?seed=1&format=npz"
        post(url, made["vox: 256^3, 2**31-1 voxels claimed"])  # the first upload's imports and pools, not counted
        time.sleep(1)
        idle = status_mb(pid, "VmRSS")
        print(f"service idle: {idle:.0f} MB resident ({args.python})")
        print(f"{'body':52} {'bytes':>5} {'status':>6} {'peak above idle':>16}  answer")
        for name, body in made.items():
            assert len(body) <= LIMIT, (name, len(body))
            Path(f"/proc/{pid}/clear_refs").write_text("5")
            idle = status_mb(pid, "VmRSS")
            status, answer = post(url, body)
            peak = status_mb(pid, "VmHWM") - idle
            detail = json.loads(answer).get("detail", "") if answer.startswith(b"{") else answer[:60]
            print(f"{name:52} {len(body):5} {status:6} {peak:13.0f} MB  {str(detail)[:90]}")


if __name__ == "__main__":
    main()
