// Arrays as the Python side has them: a flat typed array in row-major (C) order with its shape. Images are
// (H, W, 3) uint8 RGB (or float32), points (N, 2) float64 (x, y) frame or crop pixels, integer values at pixel
// centres, and a 2-D affine a (2, 3) row-major matrix [a, b, c, d, e, f] mapping (x, y) to (ax + by + c, dx + ey + f).

export type TypedArray = Uint8Array | Uint8ClampedArray | Int32Array | Float32Array | Float64Array;

export interface Tensor<T extends TypedArray = TypedArray> {
  data: T;
  shape: number[];
}

export type Affine = [number, number, number, number, number, number];

export function tensor<T extends TypedArray>(data: T, shape: number[]): Tensor<T> {
  let size = 1;
  for (const extent of shape) size *= extent;
  if (data.length !== size) throw new Error(`data of ${data.length} values cannot have shape [${shape}]`);
  return { data, shape };
}

/** (N, 2) points -> [x, y] of point i. */
export function point(points: Tensor, i: number): [number, number] {
  return [points.data[2 * i], points.data[2 * i + 1]];
}

export function checkPoints(points: Tensor, count: number | null, name: string): void {
  if (points.shape.length !== 2 || points.shape[1] !== 2 || (count !== null && points.shape[0] !== count)) {
    throw new Error(`${name} must be (${count ?? "N"}, 2) points, got [${points.shape}]`);
  }
  for (const value of points.data) if (!Number.isFinite(value)) throw new Error(`${name} must be finite`);
}

/** Array.prototype.sort's comparator for numbers, ascending: one function, where a comparator written at each sort
 * was a new closure per call that V8 optimised again every frame. */
export const ascending = (a: number, b: number): number => a - b;

/** The median as numpy gives it (the mean of the two middle values of an even count; NaN for none). */
export function median(values: number[]): number {
  const sorted = [...values].sort(ascending), middle = sorted.length >> 1;
  return sorted.length % 2 ? sorted[middle] : (sorted[middle - 1] + sorted[middle]) / 2;
}

/** The median of one column of small rows (a history's), as `median` gives it. */
export function columnMedian(rows: ArrayLike<number>[], column: number): number {
  const values: number[] = new Array(rows.length);
  for (let i = 0; i < rows.length; i++) values[i] = rows[i][column];
  return median(values);
}

/** np.percentile (linear) of `values`. */
export function percentile(values: ArrayLike<number>, q: number): number {
  const sorted = Float64Array.from(values).sort(), at = (q / 100) * (sorted.length - 1), low = Math.floor(at);
  return low + 1 < sorted.length ? sorted[low] + (sorted[low + 1] - sorted[low]) * (at - low) : sorted[low];
}
