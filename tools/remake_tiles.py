"""Give a model trained on a mesh the tiles this sinshape makes from that
mesh, its weights as they are (trainer/export.py, remake_tiles): a
geometry-only model trained before relief gets its example's relief, and a
format-5 model fresh tiles in place of those an older version made.

    pip install '.[train]' && python tools/remake_tiles.py MODEL.onnx MESH -o OUT.onnx [--asset-folder DIR]

The mesh must be the file the model was trained on (its SHA-256 is checked,
as are the level sizes and the frame its voxelisation gives); nothing is
trained again. The shipped models got their tiles so (models/*.md).
"""

import argparse
import sys

from sinshape.core.errors import InputError


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model")
    parser.add_argument("mesh")
    parser.add_argument("-o", "--output", required=True)
    parser.add_argument("--asset-folder", default=None, help="where a coloured mesh's textures lie, if not beside it")
    args = parser.parse_args()
    from sinshape.trainer.export import remake_tiles

    try:
        manifest = remake_tiles(args.model, args.mesh, args.output, args.asset_folder)
    except InputError as error:
        sys.exit(f"Error: {error}")
    kind = "colour" if "colour" in manifest else "relief"
    tiles = manifest[kind]["tiles"]
    print(f"wrote {args.output} (format 5: {tiles['count']} {kind} tiles of {tiles['side']}x{tiles['side']})")


if __name__ == "__main__":
    main()
