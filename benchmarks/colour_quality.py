"""How a coloured model's colour looks against its example's, from the same
rendered views: its colour read by correspondence (format 5) beside the
decoder's colour head (format 4's colour, still inside every format-5
model and trained the same way), side by side (docs/BENCHMARKS.md, "Colour
that looks like the example").

    python benchmarks/colour_quality.py MODEL.onnx EXAMPLE_MESH [--seeds 8]

Every view is an orthographic picture, framed on the example, in which each
pixel takes the colour at its own surface point (no lighting, no vertex
colours: the colour as a function of the point, at full detail).

- reconstruction: the example's own geometry, each pixel coloured by the
  model's reconstruction at that surface point, against the example's
  texture there: PSNR and SSIM (skimage, over the covered pixels);
- samples (seeds 1..N, their meshes at scale 2): the share of pixels whose
  colour is farther than 0.08 (sRGB, Euclidean) from every colour the
  example shows; a sliced Wasserstein distance between 5x5 colour patches
  of the samples' pictures and of the example's (256 random directions, x100);
  the colour gradient energy (mean squared difference of neighbouring
  pixels) against the example's;
- seconds to colour a sample's vertices at scale 1 both ways.
"""

import argparse
import time
from pathlib import Path

import numpy as np

VIEWS = ((30, 25), (120, 25), (210, 25), (300, 25), (0, 75))
SIZE = (384, 384)
OUT_OF_PALETTE = 0.08
PATCH = 5


def frame_views(low, high, up):
    """Per view: (camera axes, centre, pixels per unit) framing the box [low, high]."""
    from sinshape.runtime import render

    out = []
    corners = np.array(np.meshgrid(*zip(low, high), indexing="ij")).reshape(3, -1).T
    for azimuth, elevation in VIEWS:
        axes = render.camera_axes(azimuth, elevation, up)
        centre = (np.asarray(low) + high) / 2
        extent = np.abs((corners - centre) @ axes.T)[:, :2].max(axis=0)
        out.append((axes, centre, 0.92 * min(SIZE[0] / (2 * extent[0]), SIZE[1] / (2 * extent[1]))))
    return out


def surface_pixels(vertices, faces, view):
    """(mask (H, W), face (n,), weights (n, 3), points (n, 3)) of a mesh in one view."""
    from sinshape.runtime import raster

    axes, centre, scale = view
    camera = (np.asarray(vertices, np.float64) - centre) @ axes.T
    pixels = camera[:, :2] * scale * np.array([1, -1]) + np.array(SIZE) / 2
    corners = pixels[faces]
    owner, _ = raster.rasterise(corners, camera[faces][..., 2], SIZE)
    mask = owner >= 0
    face = owner[mask]
    row, col = np.nonzero(mask)
    p = np.stack([col + 0.5, row + 0.5], axis=1)
    a, b, c = corners[face, 0], corners[face, 1], corners[face, 2]
    area = raster.cross(b - a, c - a)
    w1, w2 = raster.cross(p - a, c - a) / area, raster.cross(b - a, p - a) / area
    weights = np.stack([1 - w1 - w2, w1, w2], axis=1)
    return mask, face, weights, np.einsum("nk,nkc->nc", weights, np.asarray(vertices, np.float64)[faces[face]])


def picture(mask, colours) -> np.ndarray:
    image = np.ones((*mask.shape, 3), np.float32)
    image[mask] = colours
    return image


def psnr(a, b) -> float:
    return float(10 * np.log10(1 / np.mean((a - b) ** 2)))


def ssim(a, b, mask) -> float:
    from skimage.metrics import structural_similarity

    _, full = structural_similarity(a, b, channel_axis=2, data_range=1.0, full=True)
    return float(full[mask].mean())


def patches(image, mask, count, rng) -> np.ndarray:
    """`count` random 5x5 patches (75 values) lying wholly on the shape."""
    from numpy.lib.stride_tricks import sliding_window_view

    inside = sliding_window_view(mask, (PATCH, PATCH)).all(axis=(2, 3))
    rows, cols = np.nonzero(inside)
    pick = rng.choice(len(rows), min(count, len(rows)), replace=False)
    return np.stack([image[r:r + PATCH, c:c + PATCH].ravel() for r, c in zip(rows[pick], cols[pick])])


def sliced_wasserstein(a, b, rng, directions=256) -> float:
    n = min(len(a), len(b))
    a, b = a[rng.choice(len(a), n, replace=False)], b[rng.choice(len(b), n, replace=False)]
    d = rng.normal(size=(a.shape[1], directions))
    d /= np.linalg.norm(d, axis=0)
    return float(np.mean(np.abs(np.sort(a @ d, axis=0) - np.sort(b @ d, axis=0))) * 100)


def gradient_energy(image, mask) -> float:
    dx = (image[:, 1:] - image[:, :-1]) ** 2
    dy = (image[1:] - image[:-1]) ** 2
    both_x, both_y = mask[:, 1:] & mask[:, :-1], mask[1:] & mask[:-1]
    return float((dx.sum(-1)[both_x].sum() + dy.sum(-1)[both_y].sum()) / (both_x.sum() + both_y.sum()))


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument("example")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--pictures", help="write the example, reconstruction and samples' pictures here (.png)")
    args = parser.parse_args()

    from scipy.spatial import cKDTree

    from sinshape.prep import colour as example_colour, voxelize
    from sinshape.runtime import colour, generate, load_model, mesh, query

    model = load_model(args.model)
    if model.example_tiles is None:
        raise SystemExit("a format-5 model (colour tiles) is needed: it carries both colourings")
    manifest = model.manifest
    origin, spacing = np.asarray(manifest.origin), np.asarray(manifest.spacing)
    path = Path(args.example)
    scene, _ = voxelize.read_scene(path)
    paint = example_colour.surface_painter(scene, path)
    example = voxelize.scene_mesh(scene, path, solid=False)
    vertices = (np.asarray(example.vertices) - origin) / spacing  # model units
    faces = np.asarray(example.faces)
    views = frame_views(vertices.min(axis=0), vertices.max(axis=0), manifest.up)
    rng = np.random.default_rng(0)

    def head_of(triplane):
        head = query.colouring(model, triplane)
        return lambda points: head(points)

    def tiles_of(triplane):
        read = colour.colouring(model, triplane)
        return lambda points: read(points)

    ways = {"colour head": head_of, "correspondence": tiles_of}
    recon = generate.sample(model, None)
    example_pictures, palette, rows = [], [], {name: {} for name in ways}
    recon_colour = {name: make(recon) for name, make in ways.items()}
    scores = {name: [] for name in ways}
    for view in views:
        mask, face, weights, points = surface_pixels(vertices, faces, view)
        truth = paint(face, weights)
        reference = picture(mask, truth)
        example_pictures.append((reference, mask))
        palette.append(truth)
        for name in ways:
            made = picture(mask, recon_colour[name](points))
            scores[name].append((psnr(made[mask], reference[mask]), ssim(made, reference, mask)))
            rows[name].setdefault("recon", []).append(made)
    for name in ways:
        rows[name]["psnr"] = np.mean([s[0] for s in scores[name]])
        rows[name]["ssim"] = np.mean([s[1] for s in scores[name]])
    palette = np.unique(np.round(np.concatenate(palette) * 255).astype(np.uint8), axis=0) / 255
    tree = cKDTree(palette)
    example_patches = np.concatenate([patches(image, mask, 2000, rng) for image, mask in example_pictures])
    example_energy = np.mean([gradient_energy(image, mask) for image, mask in example_pictures])

    sample_pictures = {name: [] for name in ways}
    for seed in range(1, args.seeds + 1):
        triplane = generate.sample(model, seed)
        shape = mesh.extract(model, triplane, scale=2, frame="model")
        painters = {name: make(triplane) for name, make in ways.items()}
        for view in views:
            mask, _, _, points = surface_pixels(shape.vertices, np.asarray(shape.faces), view)
            for name, read in painters.items():
                sample_pictures[name].append((picture(mask, read(points)), mask))
    for name in ways:
        pictures = sample_pictures[name]
        colours = np.concatenate([image[mask] for image, mask in pictures])
        distance, _ = tree.query(colours, workers=-1)
        rows[name]["out"] = float(np.mean(distance > OUT_OF_PALETTE) * 100)
        made = np.concatenate([patches(image, mask, 600, rng) for image, mask in pictures])
        rows[name]["swd"] = sliced_wasserstein(made, example_patches, rng)
        rows[name]["energy"] = np.mean([gradient_energy(image, mask) for image, mask in pictures]) / example_energy

    triplane = generate.sample(model, 1)
    shape = mesh.extract(model, triplane, frame="model")
    for name, make in ways.items():
        started = time.perf_counter()
        make(triplane)(shape.vertices)
        rows[name]["seconds"] = time.perf_counter() - started

    print(f"{path.name}: {len(views)} views of {SIZE[0]}x{SIZE[1]}, {args.seeds} samples; "
          f"the example shows {len(palette)} colours (8-bit)")
    print("| colour | reconstruction PSNR dB | SSIM | samples' pixels off the example's colours % "
          "| patch SWD x100 | gradient energy / example's | s to colour a sample |")
    print("|---|---|---|---|---|---|---|")
    for name, row in rows.items():
        print(f"| {name} | {row['psnr']:.1f} | {row['ssim']:.3f} | {row['out']:.2f} | {row['swd']:.2f} | "
              f"{row['energy']:.2f} | {row['seconds']:.2f} |")
    if args.pictures:
        from PIL import Image

        strip = [np.concatenate([image for image, _ in example_pictures], axis=1)]
        for name in ways:
            strip.append(np.concatenate(rows[name]["recon"], axis=1))
        for name in ways:
            for seed in range(min(args.seeds, 2)):
                strip.append(np.concatenate([image for image, _ in
                                             sample_pictures[name][seed * len(views):(seed + 1) * len(views)]], axis=1))
        Image.fromarray(np.round(np.concatenate(strip) * 255).astype(np.uint8)).save(args.pictures)


if __name__ == "__main__":
    main()
