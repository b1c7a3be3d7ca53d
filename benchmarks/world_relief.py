"""What the example's relief costs a world's tiles: a 3 x 3 block of tiles
at scale 2, with and without `detail`, no window kept, alternated twice
(docs/BENCHMARKS.md, "Endless worlds").

    python benchmarks/world_relief.py [--models terrain terrain_colour]
"""

import argparse
import time

from sinshape import models, runtime
from sinshape.runtime import world, world_points, world_tiles


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", nargs="+", default=["terrain", "terrain_colour"])
    parser.add_argument("--scale", type=float, default=2.0)
    args = parser.parse_args()
    for name in args.models:
        model = runtime.load_model(models.find(name), threads=2)
        world_tiles.tile_surface(model, 9, (50, 50), args.scale)  # the example's side of matching, made once per model
        seconds, count = {False: [], True: []}, 0
        for detail in (False, True, False, True):
            world._windows.clear()
            world_points._colourings.clear()
            started = time.perf_counter()
            count = sum(len(world_tiles.tile_surface(model, 3, (i, j), args.scale, world.WorldOptions(detail=detail)).vertices)
                        for i in range(3) for j in range(3))
            seconds[detail].append(time.perf_counter() - started)
        print(f"{name}: 3 x 3 tiles at scale {args.scale:g} ({count} vertices): without detail "
              f"{', '.join(f'{s:.2f}' for s in seconds[False])} s; with relief and correspondence "
              f"{', '.join(f'{s:.2f}' for s in seconds[True])} s")


if __name__ == "__main__":
    main()
