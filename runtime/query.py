"""Query occupancy from a tri-plane.

The decoder's first layer is applied to each plane once (stage
decoder_planes), so a point costs the sum of three hidden vectors, a ReLU
and a dot product (stage decoder_head).
"""

import numpy as np


def project_planes(model, planes: list) -> list:
    """3 x (C, H, W) -> 3 x (H, W, hidden): each plane times its W_k."""
    return [p[0] for p in model.decoder_planes.run([p[None] for p in planes])]


def grid_occupancy(model, planes: list) -> np.ndarray:
    """Occupancy on the planes' own grid: voxel (x, y, z) reads cells
    xy[x, y], xz[x, z], yz[y, z]. Returns (X, Y, Z) float32."""
    pxy, pxz, pyz = project_planes(model, planes)
    (occupancy,) = model.decoder_head.run([pxy[:, :, None], pxz[:, None], pyz[None]])
    return occupancy[..., 0]
