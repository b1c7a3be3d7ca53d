"""What a job makes: one file a route asks for (a sample in a mesh format
or as a grid, or a sample's coarse layout), normalised so that equal jobs
give equal bytes, and made by the runtime in a worker thread of the sampler.
"""

import hashlib
import io
import json
import time
from dataclasses import dataclass

import numpy as np

from sinshape.runtime import layout, layout_files, write
from sinshape.runtime.asset import AssetOptions
from sinshape.runtime.request import SampleRequest
from sinshape.serve.http import entity_tag


@dataclass(frozen=True)
class Job:
    """One file a route asks for, normalised (the runtime's request with its
    parts resolved), so that equal jobs give equal bytes: the cache's key.
    layout_of: not the sample but its layout at this level (format json, vox or npz)."""

    model: str
    request: SampleRequest
    format: str
    layout_of: int | None = None
    asset: AssetOptions | None = None  # the sample as a game asset (.glb)

    def filename(self) -> str:
        request = self.request
        tags = ["recon" if request.recon else f"seed{request.seed}"] + [f"keep{part.seed}" for part in request.keep]
        if request.tile is not None:
            tags.append(f"tile{request.tile[0]}_{request.tile[1]}")
        if request.arrange != "blend":
            tags.append(request.arrange)
        if request.heights is not None:
            tags.append("map" + hashlib.sha256(request.heights.data).hexdigest()[:8])
        if request.lod:
            tags.append(f"lod{request.lod}")
        if self.layout_of is not None:
            tags.append(f"layout{self.layout_of}")
        if request.grow:
            tags.append("grow" + "x".join(f"{f:g}" for f in request.grow))
        if request.layout:
            tags.append("layout" + hashlib.sha256(request.layout.bits).hexdigest()[:8])
        if request.size != (1.0, 1.0, 1.0):
            tags.append("size" + "x".join(f"{f:g}" for f in request.size))
        if request.scale != 1:
            tags.append(f"scale{request.scale:g}")
        if request.smooth and self.format != "npz":
            tags.append(f"smooth{request.smooth}" + ("" if request.smoother == "laplacian" else request.smoother))
        if request.largest and self.format != "npz":
            tags.append("largest")
        if request.frame == "model":
            tags.append("model")
        if self.asset:
            tags.append("asset" + "_".join(map(str, self.asset.lods)))
        return f"{self.model}_{'_'.join(tags)}.{self.format}"


@dataclass(frozen=True)
class Sample:
    """A finished file."""

    body: bytes
    etag: str  # strong: names these bytes
    faces: int | None  # None for an occupancy grid or a layout
    seconds: float  # time it took to make


def layout_file(grid: np.ndarray, level: int, format: str) -> bytes:
    """A layout as `sinrun layout` writes it (.vox, .npz), or as JSON: {shape,
    level, occupancy}, occupancy a string of '0' and '1' per cell, x slowest, z fastest."""
    if format == "vox":
        layout_files.check_fits(grid.shape, format, "the layout")
        return layout_files.vox_bytes(grid)
    if format == "npz":
        buffer = io.BytesIO()
        np.savez_compressed(buffer, layout=grid.astype(bool))
        return buffer.getvalue()
    cells = np.where(grid.ravel(), b"1", b"0").tobytes().decode()
    return json.dumps({"shape": list(grid.shape), "level": level, "occupancy": cells}).encode()


def make_sample(model, job: Job, checkpoint) -> Sample:
    """The file one job asks for, made by the runtime (in a worker thread);
    checkpoint() raises once the job is given up (the sampler's Cancelled)."""
    started = time.perf_counter()
    if job.layout_of is not None:  # a layout, not a sample
        grid = layout.layout(model, job.request.sample_seed, job.layout_of, job.request.size)
        body, faces = layout_file(grid, job.layout_of, job.format), None
    else:  # a sample, a tile of a world or a game asset, stopped within a slab when given up
        body, made = write.request_bytes(model, job.request, job.filename(), mesh_progress=checkpoint,
                                         asset=job.asset)
        faces = made["dense_triangles"] if job.asset is not None else None if made is None else len(made.faces)
    return Sample(body, entity_tag(body), faces, time.perf_counter() - started)
