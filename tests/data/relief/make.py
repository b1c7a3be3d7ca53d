"""Make the small geometry-only test mesh beside this file (run from
anywhere): a closed 2 x 1 x 1 block (z up) whose top carries ridges finer
than a voxel at res 16 (voxels of 0.125): raised 0.03 (a quarter voxel) for
0.19 of every 0.25 along x, like bricks between recessed joints, running
along y (ridged_box.ply). Deterministic: the same bytes each run."""

from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).parent
PERIOD, RAISED, HEIGHT = 0.25, 0.19, 0.03


def top(x: np.ndarray) -> np.ndarray:
    """The top's height over x: 1 in the joints, 1 + HEIGHT on the ridges."""
    return 1.0 + HEIGHT * ((x + 1.0) % PERIOD < RAISED)


def ridged_box() -> trimesh.Trimesh:
    """The block as an x-monotone profile in the xz plane (bottom at 0,
    top(x)) extruded along y from -0.5 to 0.5: quads between neighbouring
    profile columns, on both caps, the top and the bottom, and the two ends."""
    x = np.round(np.linspace(-1.0, 1.0, 129), 9)  # steps of 1/64: every ridge edge falls between two columns
    heights = top(x)
    vertices = [(xi, y, z) for y in (-0.5, 0.5) for xi, h in zip(x, heights) for z in (0.0, h)]
    n = len(x)

    def v(side: int, i: int, up: int) -> int:  # side 0: y = -0.5, 1: y = 0.5; up 0: bottom, 1: top
        return (side * n + i) * 2 + up

    quads = []
    for i in range(n - 1):
        quads.append((v(0, i, 0), v(0, i + 1, 0), v(0, i + 1, 1), v(0, i, 1)))  # cap y = -0.5, looking -y
        quads.append((v(1, i, 0), v(1, i, 1), v(1, i + 1, 1), v(1, i + 1, 0)))  # cap y = 0.5
        quads.append((v(0, i, 1), v(0, i + 1, 1), v(1, i + 1, 1), v(1, i, 1)))  # top
        quads.append((v(0, i, 0), v(1, i, 0), v(1, i + 1, 0), v(0, i + 1, 0)))  # bottom
    quads.append((v(0, 0, 0), v(0, 0, 1), v(1, 0, 1), v(1, 0, 0)))  # end x = -1
    quads.append((v(0, n - 1, 0), v(1, n - 1, 0), v(1, n - 1, 1), v(0, n - 1, 1)))  # end x = 1
    faces = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    mesh = trimesh.Trimesh(np.array(vertices, np.float64), np.array(faces), process=False)
    mesh.fix_normals()
    return mesh


def main() -> None:
    (HERE / "ridged_box.ply").write_bytes(ridged_box().export(file_type="ply"))


if __name__ == "__main__":
    main()
