"""sinshape data preparation: an example shape as voxel grids, no torch.

    from sinshape.prep import pyramid

    levels = pyramid.load_pyramid("mymesh.obj", res=64).levels  # (X, Y, Z) bool, coarsest first
    truth = pyramid.reference_grid("mymesh.obj", model.manifest)  # what `sinrun eval` scores against

Modules: voxelize (a mesh file -> a solid occupancy grid), pyramid (a mesh
or an SSG .h5 file -> the levels a model is trained on, and the reference a
model is scored against), colour (a coloured mesh's colour field per
level), shapes (procedural example meshes).

Both the trainer and evaluation prepare their data here, so a model is
scored against the grid it was trained on. It imports numpy, scipy, h5py,
trimesh and scikit-image (the prep extra installs all but numpy and
trimesh, which the runtime has), and from sinshape only core (errors, the memory
budget, the largest level side, atomic files); never torch, and nothing
from sinshape.runtime, .trainer, .cli or .serve.
"""
