"""The SSG paper's quality metrics (LP-IoU, LP-F-score, diversity) in numpy.

They follow the paper's public evaluation code (evaluation/eval_LP.py and
eval_Div.py of ChrisWu1997/SingleShapeGen), which needs torch and a GPU:

- Patches: the volume is padded with size // 2 empty voxels and cut into
  size^3 patches at the given stride (torch's `unfold`). A patch is valid if
  its central 3^3 region (2^3 for even sizes) holds both occupied and empty
  voxels, i.e. it sits on the surface. The padding counts as empty, so even a
  full volume has valid patches along its faces.
- LP of one generated shape: up to 1000 of its valid patches (a random subset
  if it has more) are each matched to the best of all valid reference
  patches; LP-IoU / LP-F is the fraction whose best IoU / F-score is > 0.95.
  Over many shapes the fractions are averaged. A shape without valid patches
  (e.g. empty) scores 0; a reference without valid patches is an InputError.
- Diversity: the mean over shapes of the mean 1 - IoU to every other shape.

Matching is one matrix product: with patches as float32 0/1 rows, the
overlaps of all pairs are A @ B.T (exact: integer sums below 2**24), in
chunks of reference patches to bound memory. Packing each patch's 1331 bits
into 21 uint64 words and popcounting their AND (np.bitwise_count) was 2-3x
slower, so it is not used. A res-128 reference has only ~600-1300 valid
patches at stride 5 (SmallTown 951, Canyon 1260, NaturalArch 579).
Measured on the 2-core development machine (load ~2 from a training job),
one BLAS thread, reference = finest level of SmallTown_r128s6 (128x46x84):

    matching 1000 patches of a 1%-flipped copy:    gemm 34 ms, popcount 62 ms
    one whole sample (lp_scores, incl. cutting):   40-50 ms
    the same upsampled 2x (3270 reference patches): 109 ms (popcount
                                                   matching alone: 318 ms)
    lp_metrics of 100 flipped and shifted copies:  3.2 s
    diversity of those 100:                        0.14 s

The per-sample time comes from this, with SSG's SmallTown_r128s6.h5 in the
current folder:

    OPENBLAS_NUM_THREADS=1 python -c "
    import h5py, numpy as np, timeit; from sinshape.runtime.evaluate import *
    v = h5py.File('SmallTown_r128s6.h5')['scale5'][:]
    ref, g = valid_patches(v), v ^ (np.random.default_rng(0).random(v.shape) < 0.01)
    print(timeit.timeit(lambda: lp_scores(g, ref, np.random.default_rng(0)), number=20) / 20)"

On cropped inputs the results agree with the paper's torch functions run on
CPU: identical patches, scores equal to float32 precision.
"""

import itertools
import json
import time
from pathlib import Path

import numpy as np

from sinshape.core.budget import check_memory
from sinshape.core.errors import InputError
from sinshape.core.files import atomic_write, check_writable

from .generate import resize_volume, sample
from .query import check_scale, dense, grid_shape

REFERENCE_CHUNK = 2048  # reference patches per matrix product: ~30 MB of work arrays
VOXEL_CHUNK = 1 << 16  # voxels per diversity product: float32 sums of 0/1 stay exact


def _occupancy(volume) -> np.ndarray:
    """(X, Y, Z) bool: bool volumes as given, others thresholded at 0.5 like the paper."""
    volume = np.asarray(volume)
    if volume.ndim != 3 or 0 in volume.shape:
        raise InputError(f"a volume must be a non-empty 3-D (X, Y, Z) array, got shape {volume.shape}")
    return volume if volume.dtype == bool else volume > 0.5


def valid_patches(volume: np.ndarray, size: int = 11, stride: int = 5) -> np.ndarray:
    """The surface patches of a volume, cut like the paper's torch `unfold`.

    volume : (X, Y, Z) bool (or occupancy, thresholded at 0.5).
    Returns (k, size, size, size) bool, in unfold's order (x start, then y, then z).
    """
    padded = np.pad(_occupancy(volume), size // 2)
    # (n0, n1, n2, size, size, size) view; starts 0, stride, ... while start + size fits.
    windows = np.lib.stride_tricks.sliding_window_view(padded, (size,) * 3)[::stride, ::stride, ::stride]
    side = 2 if size % 2 == 0 else 3
    lo = size // 2 - 1
    centre = windows[..., lo:lo + side, lo:lo + side, lo:lo + side]
    occupied = centre.sum(axis=(3, 4, 5))
    return windows[(occupied > 0) & (occupied < side**3)]


def _best_matches(generated: np.ndarray, reference: np.ndarray) -> tuple:
    """Voxel counts of each generated patch and its best reference patch.

    generated : (m, n) bool, reference : (k, n) bool, patches as flat rows.
    Returns (overlap, generated_count, reference_count), each (m,) float64:
    |A and B|, |A| and |B| for A = a generated patch and B its best match.

    "Best" is the highest F-score 2|A and B| / (|A| + |B|). IoU = F / (2 - F)
    rises with F, so the same B also has the highest IoU: one search serves
    both metrics. (The paper's F adds 1e-8 to its denominator; that moves F by
    < 1e-8, less than the gap between two distinct F values of <= 1331-voxel
    patches, > 1e-7, so it cannot change which B is best. In float32 such
    gaps stay several units in the last place apart, so rounding cannot either.)
    """
    a = generated.astype(np.float32)
    a_count = a.sum(axis=1)
    rows = np.arange(len(a))
    best_score = np.full(len(a), -1.0, np.float32)
    overlap, b_count = np.zeros(len(a)), np.zeros(len(a))
    for start in range(0, len(reference), REFERENCE_CHUNK):
        b = reference[start:start + REFERENCE_CHUNK].astype(np.float32)
        counts = b.sum(axis=1)
        chunk_overlap = a @ b.T  # (m, chunk) exact integer counts
        score = chunk_overlap / (a_count[:, None] + counts)  # F / 2
        j = score.argmax(axis=1)
        chunk_best = score[rows, j]
        better = chunk_best > best_score
        best_score[better] = chunk_best[better]
        overlap[better] = chunk_overlap[rows, j][better]
        b_count[better] = counts[j][better]
    return overlap, a_count.astype(np.float64), b_count


def lp_scores(generated: np.ndarray, reference_patches: np.ndarray, rng: np.random.Generator,
              max_patches: int = 1000, threshold: float = 0.95) -> dict:
    """LP-IoU and LP-F-score of one generated shape against the reference's patches.

    generated : (X, Y, Z) bool, any size; reference_patches : (k, s, s, s) bool
    from `valid_patches`. The generated patches are cut with the same size s
    and stride s // 2 (the paper's). `rng` picks the subset of max_patches
    when there are more valid patches than that.

    Returns {"lp_iou", "lp_f": fraction of generated patches whose best match
    scores > threshold; "mean_iou", "mean_f": mean best score; "patches": how
    many generated patches were matched}. A shape without valid patches
    scores 0 everywhere.
    """
    if len(reference_patches) == 0:
        raise InputError("the reference has no valid patches (no surface near any patch centre), so LP is undefined")
    size = reference_patches.shape[-1]
    patches = valid_patches(generated, size, size // 2)
    if len(patches) > max_patches:
        patches = patches[rng.choice(len(patches), max_patches, replace=False)]
    if len(patches) == 0:
        return {"lp_iou": 0.0, "lp_f": 0.0, "mean_iou": 0.0, "mean_f": 0.0, "patches": 0}

    overlap, a_count, b_count = _best_matches(patches.reshape(len(patches), -1),
                                              reference_patches.reshape(len(reference_patches), -1))
    iou = overlap / (a_count + b_count - overlap)
    precision, recall = overlap / a_count, overlap / b_count
    f_score = 2 * precision * recall / (precision + recall + 1e-8)  # the paper's formula
    return {"lp_iou": float(np.mean(iou > threshold)), "lp_f": float(np.mean(f_score > threshold)),
            "mean_iou": float(iou.mean()), "mean_f": float(f_score.mean()), "patches": len(patches)}


def lp_metrics(samples: list, reference: np.ndarray, seed: int = 0, max_patches: int = 1000) -> dict:
    """LP-IoU and LP-F-score of many generated shapes: the means of `lp_scores`.

    samples : list of (X, Y, Z) bool, sizes may differ; reference : (X, Y, Z) bool.
    Sample i draws its patch subset from its own generator, spawned from
    `seed`, so its scores do not depend on the other samples.

    Returns {"lp_iou", "lp_f", "mean_iou", "mean_f": means over samples,
    "reference_patches": count, "per_sample": {same keys and "patches": lists}}.
    """
    if len(samples) == 0:
        raise InputError("no samples to evaluate")
    reference_patches = valid_patches(reference)
    generators = [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(len(samples))]
    scores = [lp_scores(s, reference_patches, g, max_patches) for s, g in zip(samples, generators)]
    per_sample = {key: [s[key] for s in scores] for key in scores[0]}
    means = {key: float(np.mean(per_sample[key])) for key in ("lp_iou", "lp_f", "mean_iou", "mean_f")}
    return {**means, "reference_patches": len(reference_patches), "per_sample": per_sample}


def diversity(samples: list) -> float:
    """The paper's diversity: mean over shapes of the mean 1 - IoU to the others.

    samples : list of (X, Y, Z) bool, all the same shape (else InputError).
    One sample has nothing to differ from: diversity 0. Two empty shapes count
    as identical (IoU 1; the paper's code would divide 0 by 0).
    """
    volumes = [_occupancy(s).reshape(-1) for s in samples]
    shapes = {np.shape(s) for s in samples}
    if len(volumes) == 0:
        raise InputError("no samples to measure diversity on")
    if len(shapes) > 1:
        raise InputError(f"diversity needs samples of one shape, got {sorted(shapes)}")
    n = len(volumes)
    if n == 1:
        return 0.0
    # All pairwise overlaps as a Gram matrix, a voxel chunk at a time. numpy
    # runs x @ x.T as a symmetric product, about 1.6x faster than x @ y.T.
    overlap = np.zeros((n, n))
    for start in range(0, volumes[0].size, VOXEL_CHUNK):
        x = np.stack([v[start:start + VOXEL_CHUNK] for v in volumes]).astype(np.float32)
        overlap += x @ x.T
    count = np.diag(overlap)
    union = count[:, None] + count - overlap
    iou = np.divide(overlap, union, out=np.ones_like(union), where=union > 0)
    distance = 1 - iou
    return float(np.mean(distance.sum(axis=1) / (n - 1)))  # the diagonal is 0


def height_field(volume, up: int) -> np.ndarray:
    """Occupied voxels per column along `up`: (X, Y, Z) -> the two other axes
    in ascending order, float64 (a terrain's surface height; for any shape,
    how much stands on each spot of the ground)."""
    return _occupancy(volume).sum(axis=up, dtype=np.float64)


def height_autocorrelation(volume, up: int, axis: int, lags) -> list:
    """The height field's autocorrelation along the horizontal `axis` (an
    axis of the volume, not `up`) at each lag in voxels: each line along
    `axis` less its own mean, products at the lag over the variance, both
    averaged over all lines. A shape that repeats every L voxels along the
    axis gives about 1 at L; an unstructured one about 0."""
    if axis == up or not (0 <= axis < 3 and 0 <= up < 3):
        raise InputError(f"axis {axis} is not a horizontal axis of a volume whose up is {up}")
    height = np.moveaxis(height_field(volume, up), axis - (axis > up), 0)  # (along, across)
    height = height - height.mean(axis=0)
    variance = (height ** 2).mean()
    if not all(0 < lag < len(height) for lag in lags):
        raise InputError(f"lags must be 1 to {len(height) - 1} voxels, got {list(lags)}")
    if variance == 0:
        return [0.0 for _ in lags]
    return [float((height[:-lag] * height[lag:]).mean() / variance) for lag in lags]


def sample_volumes(model, seeds, scale: float = 1.0, upsample: bool = False, progress=None) -> list:
    """Binary occupancy grids (occupancy > 0.5) of samples at `scale`, queried
    from the tri-planes or (upsample) trilinearly upsampled from scale 1."""
    volumes = []
    for seed in seeds:
        triplane = sample(model, seed)
        if upsample:
            grid = resize_volume(dense(model, triplane, 1.0), grid_shape(triplane.size, scale))
        else:
            grid = dense(model, triplane, scale)
        volumes.append(grid > 0.5)
        if progress:
            progress()
    return volumes


def check_evaluation_memory(model, samples: int, scale: float, limit: int | None = None) -> None:
    """Refuse up front scoring that needs more than `limit` bytes (None: the
    memory available): every sample's grid is kept for diversity, whose
    pairwise overlaps are a few (n, n) float64 matrices and (n, VOXEL_CHUNK)
    float32 chunks; one sample is queried densely at a time."""
    if samples < 1:
        raise InputError(f"`samples` must be at least 1, got {samples}", "samples")
    voxels = int(np.prod(grid_shape(model.manifest.sizes[-1], scale)))
    needed = samples * voxels + 4 * 8 * samples**2 + 4 * VOXEL_CHUNK * samples + 8 * voxels
    check_memory(needed, f"scoring {samples} samples of {voxels} voxels", limit)


def evaluate_model(model, reference, samples: int = 100, first_seed: int = 0, scale: float = 1.0,
                   upsample: bool = False, progress=None, json_path=None, warn=None) -> dict:
    """Score a loaded model as the paper does, against its training input.

    reference : the mesh or SSG .h5 file it was trained on, voxelised with
    the model's own settings (prep.pyramid.reference_grid). Samples are seeds
    first_seed .. first_seed + samples - 1 at `scale`, queried from the
    tri-planes or (upsample) trilinearly upsampled from scale 1.
    progress("sampling", done, samples) is called once the request is checked
    and after each sample. warn(message), when given, is told first if the
    reference is not the file the model was trained on. Returns what
    `sinrun eval --json` writes, also to json_path when given (checked first):
    the means, sizes, timings and per-sample scores.
    """
    from sinshape.prep.pyramid import reference_grid  # the prep extra (scipy, h5py): scoring only

    check_scale(scale)
    if json_path:
        check_writable(json_path, [model.path, reference])
    unlike = not_training_input(model, reference) if warn else None
    if unlike:
        warn(unlike)
    check_evaluation_memory(model, samples, scale)
    done = itertools.count()
    step = (lambda: progress("sampling", next(done), samples)) if progress else None
    if step:
        step()  # the bar shows while the reference is made
    truth = reference_grid(reference, model.manifest, scale)
    started = time.perf_counter()
    volumes = sample_volumes(model, range(first_seed, first_seed + samples), scale, upsample, step)
    sampled = time.perf_counter()
    lp = lp_metrics(volumes, truth)
    results = {
        "model": str(model.path), "reference": str(reference), "samples": samples, "scale": scale,
        "query": "trilinear upsampling of scale 1" if upsample else "tri-plane",
        "reference_size": list(truth.shape), "sample_size": list(volumes[0].shape),
        "lp_iou": lp["lp_iou"], "lp_f": lp["lp_f"], "diversity": diversity(volumes),
        "seconds_sampling": round(sampled - started, 2), "seconds_scoring": round(time.perf_counter() - sampled, 2),
        "per_sample": lp["per_sample"],
    }
    if json_path:
        atomic_write(json_path, lambda f: f.write(json.dumps(results, indent=1).encode()))
    return results


def not_training_input(model, reference) -> str | None:
    """What is wrong when `reference` is a file, but not the one whose SHA-256
    the model's manifest records as its training input; else None."""
    from sinshape.prep.pyramid import file_sha256  # the prep extra

    source = model.manifest.raw.get("source", {})
    if not source.get("sha256") or not Path(reference).is_file() or file_sha256(Path(reference)) == source["sha256"]:
        return None
    return (f"{Path(reference).name} is not the file {model.path.name} was trained on "
            f"({source.get('name', '?')}, sha256 {source['sha256'][:12]}...): the scores compare with another shape")
