"""Give a geometry-only model trained before relief (format 3, from a mesh)
its example's relief: the depth tiles the trainer now writes, made from the
same mesh with the model's own settings (trainer/export.py, add_relief).

    pip install '.[train]' && python tools/add_relief.py MODEL.onnx MESH -o OUT.onnx

The mesh must be the file the model was trained on (its SHA-256 is checked,
as are the level sizes and the frame its voxelisation gives); nothing is
trained again, and the weights are left as they are. The shipped towerruins,
acropolis and terrain models got their tiles so (models/*.md).
"""

import argparse
import sys

from sinshape.core.errors import InputError


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("mesh")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    from sinshape.trainer.export import add_relief

    try:
        manifest = add_relief(args.model, args.mesh, args.output)
    except InputError as error:
        sys.exit(f"Error: {error}")
    tiles = manifest["relief"]["tiles"]
    print(f"wrote {args.output} (format 5: {tiles['count']} relief tiles of {tiles['side']}x{tiles['side']})")


if __name__ == "__main__":
    main()
