"""A z-buffer of projected triangles in numpy: which face each pixel's
centre sees, and where on it. Pictures (render) and an asset's bake (bake,
which rasterises UV triangles into texels) share it; it holds no mesh
library, so an asset's bake does not import trimesh through render.
"""

import numpy as np

BATCH = 1 << 20  # candidate pixels per rasterising step: bounds the memory used


def rasterise(corners: np.ndarray, nearness: np.ndarray, size, weights: bool = False):
    """Z-buffer the projected faces: for each pixel, the index of the nearest
    face covering its centre (-1 for none) and that face's nearness there
    (-inf for none), both (height, width); with `weights`, also the
    barycentric weights of that face's corners 1 and 2 at the pixel's
    centre, (height, width, 2) float32 (an asset's bake reads them).

    corners : (m, 3, 2) float pixel positions; nearness : (m, 3) float.
    """
    width, height = size
    zbuffer = np.full(width * height, -np.inf)
    owner = np.full(width * height, -1, dtype=np.int64)
    found = np.zeros((width * height, 2), np.float32) if weights else None
    for pixel, near, face, u, v in fragments(corners, nearness, size, weights):
        won = keep_nearest(pixel, near, face, zbuffer, owner)
        if weights:
            found[pixel[won]] = np.stack([u[won], v[won]], axis=1)
    if weights:
        return owner.reshape(height, width), zbuffer.reshape(height, width), found.reshape(height, width, 2)
    return owner.reshape(height, width), zbuffer.reshape(height, width)


def fragments(corners: np.ndarray, nearness: np.ndarray, size, weights: bool = False):
    """The pixel centres each projected face covers, in batches: (pixel
    indices, nearness there, faces, and with `weights` the barycentric
    weights of corners 1 and 2, else None), each (k,), for a z-buffer
    (rasterise) or several to keep.

    Faces are grouped by the width and height of their pixel bounding box,
    so that one batch tests many faces against a rectangle of candidate
    pixels of one size. Sizes are exact up to 8 pixels (most faces of a dense
    mesh) and rounded up to a power of two beyond, so there are few groups.
    """
    width, height = size
    # Columns and rows whose pixel centres (integer + 0.5) lie in each face's bounding box.
    first = np.maximum(np.ceil(corners.min(axis=1) - 0.5), 0).astype(np.int64)
    last = np.minimum(np.floor(corners.max(axis=1) - 0.5), [width - 1, height - 1]).astype(np.int64)
    a, e1, e2 = corners[:, 0], corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = cross(e1, e2)
    kept = np.flatnonzero((last >= first).all(axis=1) & (area != 0))  # covering a pixel centre
    first, span = first[kept], (last - first)[kept]
    a, e1, e2, area, nearness = a[kept], e1[kept], e2[kept], area[kept, None], nearness[kept]

    # Across a face, the barycentric weights of corners 1 and 2 and the
    # nearness are affine in the pixel position. Each is kept per face as
    # (value at the first candidate's centre, change per pixel right, per
    # pixel down). Dividing by the signed area suits either winding.
    q = first + 0.5 - a
    w1 = np.stack([cross(q, e2), e2[:, 1], -e2[:, 0]], axis=1) / area
    w2 = np.stack([cross(e1, q), -e1[:, 1], e1[:, 0]], axis=1) / area
    near = (nearness[:, :1] * [1, 0, 0] + (nearness[:, 1:2] - nearness[:, :1]) * w1
            + (nearness[:, 2:] - nearness[:, :1]) * w2)

    boxes = span + 1
    boxes = np.where(boxes <= 8, boxes, 2 ** np.ceil(np.log2(boxes)).astype(np.int64))
    # One integer per (width, height): np.unique on rows is much slower.
    groups, group_of = np.unique(boxes[:, 0] << 32 | boxes[:, 1], return_inverse=True)
    for index, (box_width, box_height) in enumerate(zip(groups >> 32, groups & 0xFFFFFFFF)):
        dy, dx = np.divmod(np.arange(box_width * box_height), box_width)  # offsets from a face's first pixel
        group = np.flatnonzero(group_of == index)
        step = max(1, BATCH // (box_width * box_height))
        for start in range(0, len(group), step):
            f = group[start:start + step]
            u = w1[f, 0, None] + w1[f, 1, None] * dx + w1[f, 2, None] * dy
            v = w2[f, 0, None] + w2[f, 1, None] * dx + w2[f, 2, None] * dy
            # The tolerance keeps a pixel centre on an edge shared by two
            # faces from being missed by both through rounding.
            inside = ((dx <= span[f, 0, None]) & (dy <= span[f, 1, None])
                      & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9))
            row, col = np.nonzero(inside)
            f, dx_in, dy_in = f[row], dx[col], dy[col]
            pixel = (first[f, 1] + dy_in) * width + first[f, 0] + dx_in
            yield (pixel, near[f, 0] + near[f, 1] * dx_in + near[f, 2] * dy_in, kept[f],
                   *((u[row, col], v[row, col]) if weights else (None, None)))


def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """z of the cross product of 2D vectors (..., 2): twice the signed triangle area."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def keep_nearest(pixel, near, face, zbuffer, owner) -> np.ndarray:
    """Depth-test fragments (k,): pixel index, nearness and face each; update
    the buffers in place. Returns which fragments won their pixel, (k,) bool."""
    np.maximum.at(zbuffer, pixel, near)  # unlike zbuffer[pixel] = ..., right when a pixel repeats
    # The fragments that set their pixel's nearness win it. Where two tie,
    # the two faces meet there, and either is right.
    won = near == zbuffer[pixel]
    owner[pixel[won]] = face[won]
    return won
