#!/usr/bin/env bash
# Renders the README's gallery with `sinrun render` (headless, CPU only).
#   bash docs/gallery/make.sh PATH/TO/towerruins.obj
# The example shapes are made here with `sinrun shape`; towerruins.obj is the
# CC-BY-4.0 mesh the towerruins model was trained on (see models/towerruins.md).
set -euo pipefail
tower=${1:?usage: make.sh PATH/TO/towerruins.obj}
cd "$(dirname "$0")"
work=$(mktemp -d)
sinrun shape terrain -o "$work/terrain.obj"
sinrun shape acropolis -o "$work/acropolis.obj"
sinrun shape painted_terrain -o "$work/painted_terrain.ply"
sinrun shape brick_ruin -o "$work/brick_ruin.glb"

# Each model: its training shape, then samples at the training size.
sinrun render "$tower" towerruins --seeds 1-4 --scale 2 --columns 5 --image-size 256 -o towerruins.png
sinrun render "$work/terrain.obj" terrain --seeds 1-4 --scale 2 --up z --columns 5 --image-size 256 -o terrain.png
sinrun render "$work/acropolis.obj" acropolis --seeds 1-4 --scale 2 --up z --columns 5 --image-size 256 -o acropolis.png
sinrun render "$work/painted_terrain.ply" terrain_colour --seeds 1-4 --scale 2 --up z --columns 5 --image-size 256 -o terrain_colour.png
sinrun render "$work/brick_ruin.glb" brickruin --seeds 1-4 --scale 2 --up z --columns 5 --image-size 256 -o brickruin.png
# A textured example's colour at its own detail: the ruin and a sample, close up.
sinrun render "$work/brick_ruin.glb" brickruin --seeds 2 --scale 4 --up z --zoom 2 --focus 0.5,0.0,0.4 --azimuth 10 --elevation 10 --image-size 384 -o brickruin_closeup.png

# Other sizes and aspect ratios: twice as long, twice as wide, half as deep.
sinrun render terrain --seeds 5 --size 2,1,1 --scale 2 --up z --image-size 384 -o terrain_2x1.png
sinrun render acropolis --seeds 5 --size 2,1,1 --scale 2 --up z --image-size 384 -o acropolis_2x1.png
sinrun render acropolis --seeds 6 --size 1,2,1 --scale 2 --up z --image-size 384 -o acropolis_1x2.png
sinrun render towerruins --seeds 5 --size 2,1,2 --scale 2 --image-size 384 -o towerruins_2x1x2.png

# Resolution: the same sample queried at scale 1 and at scale 8, close up.
sinrun render towerruins --seeds 3 --scale 1 --zoom 3 --focus 0.5,0.8,1 --image-size 384 -o closeup_scale1.png
sinrun render towerruins --seeds 3 --scale 8 --zoom 3 --focus 0.5,0.8,1 --image-size 384 -o closeup_scale8.png

# Endless worlds (docs/WORLDS.md): an 8 x 8 block of terrain tiles; the terrain's tiles shaped by a
# painted height map (world_map.png: a pixel a square of a tile's longer side, 31 voxels: 16 x 25 of the
# terrain's 31 x 20 tiles hold its 16 x 16 pixels; white 120 voxels up); temples scattered over the same map
# (12 x 21 of their 31 x 18 tiles); tower ruins scattered on flat ground; temples and towers on the same map,
# a model map (world_models_map.png: 0 temple, 1 tower, pixels as the height map's) saying which goes where.
sinrun world terrain --seed 3 --tiles 0:7,0:7 --scale 2 -o "$work/terrain_world.ply"
sinrun render "$work/terrain_world.ply" --up z --image-size 640 --elevation 40 --azimuth 30 -o world_terrain.png
sinrun world terrain --seed 3 --tiles 0:15,0:24 --map world_map.png --relief 120 -o "$work/painted.ply"
sinrun render "$work/painted.ply" --up z --image-size 900 --elevation 30 --azimuth 210 -o world_painted.png
sinrun world acropolis --seed 3 --tiles 0:11,0:20 --map world_map.png --relief 60 -o "$work/temples.ply"
sinrun render "$work/temples.ply" --up z --image-size 900 --elevation 35 --azimuth 210 -o world_acropolis.png
sinrun world towerruins --seed 3 --tiles 0:11,0:11 -o "$work/towers.ply"
sinrun render "$work/towers.ply" --up y --image-size 900 --elevation 35 --azimuth 30 -o world_towerruins.png
sinrun world acropolis towerruins --seed 3 --tiles 0:11,0:20 --models-map world_models_map.png --map world_map.png \
    --relief 60 -o "$work/temples_and_towers.ply"
sinrun render "$work/temples_and_towers.ply" --up z --image-size 900 --elevation 35 --azimuth 210 -o world_models.png

# Relief of a geometry-only model: the tower at scale 4, close up on its wall: the example, then seed 3
# without its example's relief (--no-detail), the reconstruction with it, and seed 3 with it.
sinrun sample towerruins --seed 3 --scale 4 --no-detail -o "$work/tower_plain.ply"
sinrun sample towerruins --recon --scale 4 -o "$work/tower_recon_relief.ply"
sinrun sample towerruins --seed 3 --scale 4 -o "$work/tower_relief.ply"
sinrun render "$tower" "$work/tower_plain.ply" "$work/tower_recon_relief.ply" "$work/tower_relief.ply" --zoom 2.5 \
    --focus 0.5,0.55,0.9 --columns 4 --image-size 320 -o tower_relief.png

# A wall whose bricks stand out of recessed mortar, trained here (about 4 minutes), close up at scale 4: its
# reconstruction and two samples, read coarse to fine with the example's relief (docs/BENCHMARKS.md, "Relief";
# the picture in the docs has the previous runtime's row above, drawn with the commit before).
sinrun shape relief_wall -o "$work/relief_wall.ply"
OMP_NUM_THREADS=1 sinrun train "$work/relief_wall.ply" -o "$work/wall.onnx" --res 48 --iters 300 --up z
sinrun render "$work/relief_wall.ply" "$work/wall.onnx" --recon --seeds 1,2 --scale 4 --up z --zoom 3 --focus 0.3,0.0,0.4 --azimuth 20 --elevation 10 --columns 4 --image-size 320 -o relief_wall_now.png
rm -r "$work"
