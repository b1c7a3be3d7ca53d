// Where an edit lies in the model's frame, by the browser runtime's own
// rules (sinshape/generate.js's sizes, edit.js's parts): pure functions of a
// model's `info` ({ sizes, origin, spacing }: its levels' grids and frame)
// and a sample request, nothing of three.js or of the page.
import { scaledSizes } from '../sinshape/generate.js';
import { grownPart, readPart } from '../sinshape/edit.js';

/** The finest grid of a sample `factors` times the training size. */
export const finestSize = (info, factors) => scaledSizes(info.sizes, factors).at(-1);

/** Voxels of the finest grid -> the model's frame, where the meshes are. */
const toFrame = (info, voxel) => voxel.map((v, a) => info.origin[a] + info.spacing[a] * v);

/**
 * The boxes an edit keeps, in the model's frame ([{ low, high }]): each kept
 * part, or where the old sample sits in the grown one; none for other requests.
 */
export function keptBoxes(info, request) {
  const finest = finestSize(info, request.size);
  const parts = request.grow ? [grownPart(info.sizes, request.seed, request.grow, request.anchor ?? [0, 0, 0], request.size).part]
    : request.keep.map((part) => (typeof part === 'string' ? readPart(part, info, finest) : part));
  return parts.map(({ low, high }) => ({ low: toFrame(info, low), high: toFrame(info, high) }));
}
