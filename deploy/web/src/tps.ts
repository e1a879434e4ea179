// Regularised thin-plate-spline warps and the warp-guided generator's references: landmarks/warp/tps.py (fit_tps,
// merge_close_points, border_points, folded_fraction, fit_similarity, tps_grid_map, tps_map, tps_maps,
// landmark_distance, nearest_shots, warp_references). Same defaults, same merging of close points, fixed border
// points, regularisation in unit-RMS coordinates, condition check, fold check, retries (10x, 100x lambda) and the
// similarity / identity fallbacks; the maps are made on a coarse grid and interpolated bilinearly, then the shots
// are sampled with OpenCV's bicubic (remap.ts). Plain float64 arithmetic where Python evaluates the kernel in
// float32: the maps agree to ~1e-3 px.

import { CoarseGrid, coarseGrid, densifyGrid } from "./remap.js";
import { Tensor, tensor } from "./tensor.js";
import { evaluateSpline, splineLog } from "./tps_wasm.js";

export const DEFAULT_REGULARIZATION = 1e-3;
export const DEFAULT_MERGE_DISTANCE = 1.0;  // pixels
export const DEFAULT_MAX_CONDITION = 1e10;
export const DEFAULT_MAX_FOLDED_FRACTION = 0.0;
export const RETRY_FACTORS = [1.0, 10.0, 100.0];
export type WarpMethod = "tps" | "tps_stronger" | "similarity" | "identity";

/** tps_map's keyword options (its defaults where not given). */
export interface TpsSettings {
  regularization?: number;
  mergeDistance?: number;
  maxCondition?: number;
  maxFoldedFraction?: number;
  fixBorder?: boolean;
  gridStep?: number;
}

function options(settings: TpsSettings = {}): Required<TpsSettings> {
  return {
    regularization: settings.regularization ?? DEFAULT_REGULARIZATION,
    mergeDistance: settings.mergeDistance ?? DEFAULT_MERGE_DISTANCE,
    maxCondition: settings.maxCondition ?? DEFAULT_MAX_CONDITION,
    maxFoldedFraction: settings.maxFoldedFraction ?? DEFAULT_MAX_FOLDED_FRACTION,
    fixBorder: settings.fixBorder ?? true,
    gridStep: settings.gridStep ?? 1,
  };
}

/** The TPS system cannot be solved reliably (internal: triggers the fallbacks). */
class DegenerateTpsError extends Error {}

/** Python's "{:.3g}" (for the reasons' text). */
function formatG(value: number): string {
  if (!Number.isFinite(value) || value === 0) return String(value).replace("Infinity", "inf");
  const exponent = Math.floor(Math.log10(Math.abs(Number(value.toPrecision(3)))));
  if (exponent >= -4 && exponent < 3) return String(Number(value.toPrecision(3)));
  const [mantissa, power] = Number(value.toPrecision(3)).toExponential().split("e");
  return `${mantissa}e${power[0]}${power.slice(1).padStart(2, "0")}`;
}

// ---- the spline ---------------------------------------------------------------------------------------------

/** A fitted TPS R^2 -> R^D (D / 2 maps onto the same control points). */
export interface ThinPlateSpline {
  control: Float64Array;  // (N, 2) normalised control points
  centre: [number, number];
  scale: number;
  weights: Float64Array;  // (N, D) kernel weights
  affine: Float64Array;  // (3, D) rows: constant, x, y
  columns: number;
  condition: number;
}

function kernel(squared: number): number {
  return squared > 0 ? squared * Math.log(squared) : 0;  // U(r) = r^2 log r^2, 0 at r = 0
}

/** Eigenvalues of a symmetric (n, n) matrix (Householder to tridiagonal, then implicit QL); a copy is made. */
function symmetricEigenvalues(matrix: Float64Array, n: number): Float64Array {
  const z = Float64Array.from(matrix), d = new Float64Array(n), e = new Float64Array(n);
  for (let i = n - 1; i > 0; i--) {
    const l = i - 1;
    let h = 0, scale = 0;
    if (l > 0) {
      for (let k = 0; k < i; k++) scale += Math.abs(z[i * n + k]);
      if (scale === 0) e[i] = z[i * n + l];
      else {
        for (let k = 0; k < i; k++) { z[i * n + k] /= scale; h += z[i * n + k] * z[i * n + k]; }
        let f = z[i * n + l];
        let g = f >= 0 ? -Math.sqrt(h) : Math.sqrt(h);
        e[i] = scale * g;
        h -= f * g;
        z[i * n + l] = f - g;
        f = 0;
        for (let j = 0; j < i; j++) {
          g = 0;
          for (let k = 0; k <= j; k++) g += z[j * n + k] * z[i * n + k];
          for (let k = j + 1; k < i; k++) g += z[k * n + j] * z[i * n + k];
          e[j] = g / h;
          f += e[j] * z[i * n + j];
        }
        const hh = f / (h + h);
        for (let j = 0; j < i; j++) {
          f = z[i * n + j];
          e[j] = g = e[j] - hh * f;
          for (let k = 0; k <= j; k++) z[j * n + k] -= f * e[k] + g * z[i * n + k];
        }
      }
    } else e[i] = z[i * n + l];
    d[i] = h;
  }
  e[0] = 0;
  for (let i = 0; i < n; i++) d[i] = z[i * n + i];
  for (let i = 1; i < n; i++) e[i - 1] = e[i];
  e[n - 1] = 0;
  for (let l = 0; l < n; l++) {
    let iter = 0, m: number;
    do {
      for (m = l; m < n - 1; m++) {
        if (Math.abs(e[m]) <= Number.EPSILON * (Math.abs(d[m]) + Math.abs(d[m + 1]))) break;
      }
      if (m !== l) {
        if (iter++ === 60) { d.fill(NaN); return d; }
        let g = (d[l + 1] - d[l]) / (2 * e[l]);
        let r = Math.hypot(g, 1);
        g = d[m] - d[l] + e[l] / (g + (g >= 0 ? r : -r));
        let s = 1, c = 1, p = 0, i: number;
        for (i = m - 1; i >= l; i--) {
          const f = s * e[i], b = c * e[i];
          e[i + 1] = r = Math.hypot(f, g);
          if (r === 0) { d[i + 1] -= p; e[m] = 0; break; }
          s = f / r;
          c = g / r;
          g = d[i + 1] - p;
          r = (d[i] - g) * s + 2 * c * b;
          d[i + 1] = g + (p = s * r);
          g = c * r - b;
        }
        if (r === 0 && i >= l) continue;
        d[l] -= p;
        e[l] = g;
        e[m] = 0;
      }
    } while (m !== l);
  }
  return d;
}

/** Solve a x = b for (n, n) a and (n, columns) b in place (Gaussian elimination, partial pivoting): b becomes x. */
function solve(a: Float64Array, b: Float64Array, n: number, columns: number): void {
  for (let k = 0; k < n; k++) {
    let pivot = k;
    for (let i = k + 1; i < n; i++) if (Math.abs(a[i * n + k]) > Math.abs(a[pivot * n + k])) pivot = i;
    if (a[pivot * n + k] === 0) throw new DegenerateTpsError("TPS system is singular");
    if (pivot !== k) {  // rows swapped in place: no copies made per pivot (each a buffer for the collector)
      for (let j = 0; j < n; j++) { const t = a[k * n + j]; a[k * n + j] = a[pivot * n + j]; a[pivot * n + j] = t; }
      for (let j = 0; j < columns; j++) {
        const t = b[k * columns + j]; b[k * columns + j] = b[pivot * columns + j]; b[pivot * columns + j] = t;
      }
    }
    const diagonal = a[k * n + k];
    for (let i = k + 1; i < n; i++) {
      const factor = a[i * n + k] / diagonal;
      if (factor === 0) continue;
      for (let j = k + 1; j < n; j++) a[i * n + j] -= factor * a[k * n + j];
      for (let j = 0; j < columns; j++) b[i * columns + j] -= factor * b[k * columns + j];
    }
  }
  for (let k = n - 1; k >= 0; k--) {
    for (let j = 0; j < columns; j++) {
      let sum = b[k * columns + j];
      for (let i = k + 1; i < n; i++) sum -= a[k * n + i] * b[i * columns + j];
      b[k * columns + j] = sum / a[k * n + k];
    }
  }
}

/** The (regularised) TPS with f(control[i]) ~= values[i] (landmarks.warp.tps.fit_tps). control: (N, 2) flat; values:
 * (N, columns) flat. Throws DegenerateTpsError (N < 3, no spread, condition number over maxCondition). */
function solveTps(control: Float64Array, values: Float64Array, columns: number, regularization: number,
                  maxCondition: number): ThinPlateSpline {
  const count = control.length / 2;
  if (count < 3) throw new DegenerateTpsError(`a TPS needs >= 3 control points, got ${count}`);
  let cx = 0, cy = 0;
  for (let i = 0; i < count; i++) { cx += control[2 * i]; cy += control[2 * i + 1]; }
  cx /= count; cy /= count;
  let spread = 0;
  for (let i = 0; i < count; i++) spread += (control[2 * i] - cx) ** 2 + (control[2 * i + 1] - cy) ** 2;
  const scale = Math.sqrt(spread / count);
  if (!(scale > 1e-9)) throw new DegenerateTpsError("control points have no spread");
  const normalised = new Float64Array(2 * count);
  for (let i = 0; i < count; i++) {
    normalised[2 * i] = (control[2 * i] - cx) / scale;
    normalised[2 * i + 1] = (control[2 * i + 1] - cy) / scale;
  }
  const n = count + 3, system = new Float64Array(n * n);
  for (let i = 0; i < count; i++) {
    for (let j = 0; j < count; j++) {
      const dx = normalised[2 * i] - normalised[2 * j], dy = normalised[2 * i + 1] - normalised[2 * j + 1];
      system[i * n + j] = kernel(dx * dx + dy * dy) + (i === j ? regularization : 0);
    }
    system[i * n + count] = system[count * n + i] = 1;
    system[i * n + count + 1] = system[(count + 1) * n + i] = normalised[2 * i];
    system[i * n + count + 2] = system[(count + 2) * n + i] = normalised[2 * i + 1];
  }
  const eigenvalues = symmetricEigenvalues(system, n);
  let largest = 0, smallest = Infinity;
  for (const value of eigenvalues) {
    largest = Math.max(largest, Math.abs(value));
    smallest = Math.min(smallest, Math.abs(value));
  }
  const condition = largest / smallest;
  if (!Number.isFinite(condition) || condition > maxCondition) {
    throw new DegenerateTpsError(`TPS system ill-conditioned (condition number ${formatG(condition)})`);
  }
  const solution = new Float64Array(n * columns);
  solution.set(values.subarray(0, count * columns));
  solve(system, solution, n, columns);
  return { control: normalised, centre: [cx, cy], scale, weights: solution.slice(0, count * columns),
           affine: solution.slice(count * columns), columns, condition };
}

/** The spline at points (M, 2) flat -> (M, columns) flat (ThinPlateSpline.dense). Each output is summed in the
 * same order as a plain loop would (affine part, then the kernel terms by control point); four (or two) outputs
 * share each pass over the kernel row. In WebAssembly where it runs (tps_wasm.ts), else here. */
function evaluate(spline: ThinPlateSpline, points: Float64Array): Float64Array {
  const { control, weights, affine, columns, scale } = spline, [cx, cy] = spline.centre;
  const fast = evaluateSpline(control, weights, affine, columns, spline.centre, scale, points);  // the same values
  if (fast !== null) return fast;
  const count = control.length / 2, total = points.length / 2;
  const out = new Float64Array(total * columns), row = new Float64Array(count);
  const transposed = new Float64Array(count * columns);  // (columns, N): each output's weights contiguous
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < columns; c++) transposed[c * count + i] = weights[i * columns + c];
  }
  const start = (c: number, x: number, y: number) => affine[c] + x * affine[columns + c] + y * affine[2 * columns + c];
  for (let p = 0; p < total; p++) {
    const x = (points[2 * p] - cx) / scale, y = (points[2 * p + 1] - cy) / scale, o = p * columns;
    for (let i = 0; i < count; i++) {
      const dx = x - control[2 * i], dy = y - control[2 * i + 1], squared = dx * dx + dy * dy;
      row[i] = squared > 0 ? squared * splineLog(squared) : 0;  // the kernel, with tps_wasm.ts's log
    }
    let c = 0;
    for (; c + 3 < columns; c += 4) {
      let s0 = start(c, x, y), s1 = start(c + 1, x, y), s2 = start(c + 2, x, y), s3 = start(c + 3, x, y);
      for (let i = 0, w = c * count; i < count; i++, w++) {
        const k = row[i];
        s0 += k * transposed[w]; s1 += k * transposed[w + count];
        s2 += k * transposed[w + 2 * count]; s3 += k * transposed[w + 3 * count];
      }
      out[o + c] = s0; out[o + c + 1] = s1; out[o + c + 2] = s2; out[o + c + 3] = s3;
    }
    for (; c + 1 < columns; c += 2) {
      let s0 = start(c, x, y), s1 = start(c + 1, x, y);
      for (let i = 0, w = c * count; i < count; i++, w++) {
        const k = row[i];
        s0 += k * transposed[w]; s1 += k * transposed[w + count];
      }
      out[o + c] = s0; out[o + c + 1] = s1;
    }
    for (; c < columns; c++) {
      let sum = start(c, x, y);
      for (let i = 0, w = c * count; i < count; i++) sum += row[i] * transposed[w + i];
      out[o + c] = sum;
    }
  }
  return out;
}

/** A spline's parts (fitTps's; control (N, 2) normalised, weights (N, D), affine (3, D)) at points (M, 2) -> (M, D)
 * (ThinPlateSpline.dense on tensors: the tests compare its WebAssembly with its JavaScript). */
export function splineAt(control: Tensor, weights: Tensor, affine: Tensor, centre: [number, number], scale: number,
                         points: Tensor): Tensor<Float64Array> {
  const columns = weights.shape[1], f64 = (t: Tensor) => Float64Array.from(t.data);
  const spline = { control: f64(control), weights: f64(weights), affine: f64(affine), columns, centre, scale, condition: 0 };
  return tensor(evaluate(spline, f64(points)), [points.shape[0], columns]);
}

/** landmarks.warp.tps.fit_tps on tensors: control (N, 2), values (N, D) -> the spline's parts and condition number. */
export function fitTps(controlPoints: Tensor, values: Tensor, regularization = DEFAULT_REGULARIZATION,
                       maxCondition = DEFAULT_MAX_CONDITION): { weights: Tensor<Float64Array>;
                         affine: Tensor<Float64Array>; condition: number; centre: number[]; scale: number } {
  const columns = values.shape[1];
  const spline = solveTps(Float64Array.from(controlPoints.data), Float64Array.from(values.data), columns,
                          regularization, maxCondition);
  return { weights: tensor(spline.weights, [spline.weights.length / columns, columns]),
           affine: tensor(spline.affine, [3, columns]), condition: spline.condition, centre: spline.centre,
           scale: spline.scale };
}

/** Whether control points i and j ((N, 2) flat) lie closer than sqrt(limit). Module functions here and below, not
 * closures made per call, which V8 optimised again on every frame. */
function closePoints(control: Float64Array, i: number, j: number, limit: number): boolean {
  return (control[2 * i] - control[2 * j]) ** 2 + (control[2 * i + 1] - control[2 * j + 1]) ** 2 < limit;
}

/** Greedily merge control points closer than minDistance, their values averaged; first occurrence order kept
 * (landmarks.warp.tps.merge_close_points). control (N, 2), values (N, columns), flat. */
function mergeClosePoints(control: Float64Array, values: Float64Array, columns: number, minDistance: number
                          ): [Float64Array, Float64Array] {
  const count = control.length / 2, limit = minDistance * minDistance;
  let any = false;
  for (let i = 0; i < count && !any; i++) {
    for (let j = i + 1; j < count; j++) if (closePoints(control, i, j, limit)) { any = true; break; }
  }
  if (!any) return [control, values];
  const owner = new Int32Array(count).fill(-1), clusters: number[][] = [];
  for (let index = 0; index < count; index++) {
    if (owner[index] >= 0) continue;
    const members: number[] = [];
    for (let j = 0; j < count; j++) if (owner[j] < 0 && closePoints(control, index, j, limit)) members.push(j);
    if (members.length === 0) members.push(index);
    for (const j of members) owner[j] = clusters.length;
    clusters.push(members);
  }
  const mergedControl = new Float64Array(2 * clusters.length);
  const mergedValues = new Float64Array(columns * clusters.length);
  for (let c = 0; c < clusters.length; c++) {
    const members = clusters[c];
    for (const j of members) {
      mergedControl[2 * c] += control[2 * j] / members.length;
      mergedControl[2 * c + 1] += control[2 * j + 1] / members.length;
      for (let k = 0; k < columns; k++) mergedValues[c * columns + k] += values[j * columns + k] / members.length;
    }
  }
  return [mergedControl, mergedValues];
}

/** The 4 frame corners and 4 edge midpoints, (8, 2) flat (landmarks.warp.tps.border_points). */
function borderPoints(height: number, width: number): number[] {
  const right = width - 1, bottom = height - 1;
  return [0, 0, right / 2, 0, right, 0, right, bottom / 2, right, bottom, right / 2, bottom, 0, bottom, 0, bottom / 2];
}

/** np.gradient of a (rows, cols) grid `m` at (i, j), along its rows or its columns. */
function gridGradient(m: Float64Array, rows: number, cols: number, i: number, j: number, alongRows: boolean): number {
  const n = alongRows ? rows : cols, k = alongRows ? i : j, step = alongRows ? cols : 1, at = i * cols + j;
  if (n < 2) return 0;
  if (k === 0) return m[at + step] - m[at];
  if (k === n - 1) return m[at] - m[at - step];
  return (m[at + step] - m[at - step]) / 2;
}

/** Share of the grid where the map folds: Jacobian determinant <= 0 (np.gradient along each axis). */
export function foldedFraction(mapX: Float64Array, mapY: Float64Array, rows: number, cols: number): number {
  let folded = 0;
  for (let i = 0; i < rows; i++) {
    for (let j = 0; j < cols; j++) {
      const determinant = gridGradient(mapX, rows, cols, i, j, false) * gridGradient(mapY, rows, cols, i, j, true)
        - gridGradient(mapX, rows, cols, i, j, true) * gridGradient(mapY, rows, cols, i, j, false);
      if (!(determinant > 0)) folded++;
    }
  }
  return folded / (rows * cols);
}

/** Least-squares similarity (no reflection) control -> values: an affine [a, b, c, d, e, f], or null when the
 * control points have no spread (landmarks.warp.tps.fit_similarity). */
function fitSimilarity(control: Float64Array, values: Float64Array): number[] | null {
  const count = control.length / 2;
  let sx = 0, sy = 0, vx = 0, vy = 0;
  for (let i = 0; i < count; i++) {
    sx += control[2 * i]; sy += control[2 * i + 1]; vx += values[2 * i]; vy += values[2 * i + 1];
  }
  sx /= count; sy /= count; vx /= count; vy /= count;
  let variance = 0, c00 = 0, c01 = 0, c10 = 0, c11 = 0;
  for (let i = 0; i < count; i++) {
    const px = control[2 * i] - sx, py = control[2 * i + 1] - sy, qx = values[2 * i] - vx, qy = values[2 * i + 1] - vy;
    variance += px * px + py * py;
    c00 += qx * px; c01 += qx * py; c10 += qy * px; c11 += qy * py;
  }
  variance /= count;
  if (!(variance > 1e-9)) return null;
  const h = Math.hypot(c00 + c11, c10 - c01) / count;  // the proper rotation's trace(R^T C), 2-D closed form
  const scale = h / variance;
  if (!(scale > 1e-6)) return null;
  const cos = (c00 + c11) / count / h, sin = (c10 - c01) / count / h;
  const a = scale * cos, b = -scale * sin, d = scale * sin, e = scale * cos;
  return [a, b, vx - (a * sx + b * sy), d, e, vy - (d * sx + e * sy)];
}

// ---- maps ---------------------------------------------------------------------------------------------------

/** A backward map on its grid (landmarks.warp.tps.GridMap): output (x, y) samples the source at (mapX, mapY);
 * mapX, mapY: (grid rows, grid cols) flat; `densifyGrid(grid, ...)` makes per-pixel values. */
export interface GridMap {
  mapX: Float64Array;
  mapY: Float64Array;
  method: WarpMethod;
  regularization: number;
  foldedFraction: number;
  reason: string;
  grid: CoarseGrid;
}

/** A dense backward map (landmarks.warp.tps.WarpMap): (H, W) float32 source pixel coordinates. */
export interface WarpMap {
  mapX: Float32Array;
  mapY: Float32Array;
  method: WarpMethod;
  regularization: number;
  foldedFraction: number;
  reason: string;
}

function finiteRows(points: Tensor): boolean[] {
  const rows: boolean[] = [];
  for (let i = 0; i < points.shape[0]; i++) {
    rows.push(Number.isFinite(points.data[2 * i]) && Number.isFinite(points.data[2 * i + 1]));
  }
  return rows;
}

/** The indices where `flags` (and `also`, where given) hold. Loops, not closures made per call: V8 optimised those
 * again on every frame. */
function indicesWhere(flags: boolean[], also: boolean[] | null = null): number[] {
  const out: number[] = [];
  for (let i = 0; i < flags.length; i++) if (flags[i] && (also === null || also[i])) out.push(i);
  return out;
}

/** Whether `rows` holds wherever `needed` does. */
function covers(rows: boolean[], needed: boolean[]): boolean {
  for (let i = 0; i < needed.length; i++) if (needed[i] && !rows[i]) return false;
  return true;
}

function checkPair(source: Tensor, target: Tensor): void {
  if (source.shape.length !== 2 || source.shape[1] !== 2 || target.shape.length !== 2
      || target.shape[0] !== source.shape[0] || target.shape[1] !== 2) {
    throw new Error(`point sets must both be (N, 2), got [${source.shape}], [${target.shape}]`);
  }
}

/** The target's rows (control points) and each source set's (two value columns per set), then the fixed points
 * mapped onto themselves: (control (N, 2), values (N, 2 * sets)), flat. */
function controlPoints(target: Tensor, sources: Tensor[], rows: number[], fixed: number[]
                       ): [Float64Array, Float64Array] {
  const columns = 2 * sources.length, count = rows.length + fixed.length / 2;
  const control = new Float64Array(2 * count), values = new Float64Array(columns * count);
  for (let r = 0; r < count; r++) {
    const row = rows[r], f = r - rows.length, x = fixed[2 * f], y = fixed[2 * f + 1];  // fixed: past the rows
    control[2 * r] = row === undefined ? x : target.data[2 * row];
    control[2 * r + 1] = row === undefined ? y : target.data[2 * row + 1];
    for (let slot = 0; slot < sources.length; slot++) {
      values[r * columns + 2 * slot] = row === undefined ? x : sources[slot].data[2 * row];
      values[r * columns + 2 * slot + 1] = row === undefined ? y : sources[slot].data[2 * row + 1];
    }
  }
  return [control, values];
}

/** A set's map out of the spline's values on the grid (two columns of `columns`): (mapX, mapY, all finite). */
function slotMap(mapped: Float64Array, columns: number, slot: number): [Float64Array, Float64Array, boolean] {
  const size = mapped.length / columns, mapX = new Float64Array(size), mapY = new Float64Array(size);
  let finite = true;
  for (let p = 0; p < size; p++) {
    mapX[p] = mapped[p * columns + 2 * slot];
    mapY[p] = mapped[p * columns + 2 * slot + 1];
    if (!Number.isFinite(mapX[p]) || !Number.isFinite(mapY[p])) finite = false;
  }
  return [mapX, mapY, finite];
}

/** tps_map on its grid, not yet dense (landmarks.warp.tps.tps_grid_map): the backward map of the warp that moves
 * sourcePoints (N, 2) onto targetPoints (N, 2) in an (H, W) frame (rows with NaN ignored). Never throws for
 * degenerate point sets: retries with more regularisation, then a similarity, then the identity. */
export function tpsGridMap(sourcePoints: Tensor, targetPoints: Tensor, height: number, width: number,
                           settings: TpsSettings = {}): GridMap {
  checkPair(sourcePoints, targetPoints);
  const o = options(settings), targetRows = finiteRows(targetPoints);
  const found = indicesWhere(finiteRows(sourcePoints), targetRows);
  const [targets, sources] = controlPoints(targetPoints, [sourcePoints], found, []);
  const fixed = o.fixBorder ? borderPoints(height, width) : [];
  const [control, values] = mergeClosePoints(...controlPoints(targetPoints, [sourcePoints], found, fixed), 2,
                                             o.mergeDistance);
  const grid = coarseGrid(height, width, o.gridStep);
  return gridTries(control, values, 1, grid, o,
                   (_, reasons) => rigidGridMap(targets, sources, found.length, grid, reasons))[0];
}

/** tpsGridMap's tries for `sets` sets of values (two columns each) on the same merged control points
 * (landmarks.warp.tps._grid_maps): lambda times each of RETRY_FACTORS until one neither fails nor folds, each try one
 * solve for every set still without a map; a set whose tries all fail or fold takes `fallback(slot, reasons)`. */
function gridTries(control: Float64Array, values: Float64Array, sets: number, grid: CoarseGrid,
                   o: Required<TpsSettings>, fallback: (slot: number, reasons: string[]) => GridMap): GridMap[] {
  const maps: (GridMap | null)[] = new Array(sets).fill(null), reasons: string[][] = maps.map(() => []);
  const count = control.length / 2, columns = 2 * sets;
  let pending = maps.map((_, slot) => slot);
  for (let attempt = 0; attempt < RETRY_FACTORS.length && pending.length > 0; attempt++) {
    const lambda = o.regularization * RETRY_FACTORS[attempt], span = 2 * pending.length;
    const picked = new Float64Array(count * span);
    for (let r = 0; r < count; r++) {
      for (let column = 0; column < pending.length; column++) {
        const slot = pending[column];
        picked[r * span + 2 * column] = values[r * columns + 2 * slot];
        picked[r * span + 2 * column + 1] = values[r * columns + 2 * slot + 1];
      }
    }
    let spline: ThinPlateSpline;
    try {
      spline = solveTps(control, picked, span, lambda, o.maxCondition);
    } catch (error) {
      if (!(error instanceof DegenerateTpsError)) throw error;
      for (const slot of pending) reasons[slot].push(error.message);
      break;  // more regularisation does not help a system without spread / affine rank
    }
    const mapped = evaluate(spline, grid.points), left: number[] = [];
    for (let column = 0; column < pending.length; column++) {
      const slot = pending[column], [mapX, mapY, finite] = slotMap(mapped, span, column);
      const folds = foldedFraction(mapX, mapY, grid.ys.length, grid.xs.length);
      if (finite && folds <= o.maxFoldedFraction) {
        maps[slot] = { mapX, mapY, method: attempt === 0 ? "tps" : "tps_stronger", regularization: lambda,
                       foldedFraction: folds, reason: reasons[slot].join("; "), grid };
      } else {
        reasons[slot].push(foldedReason(lambda, folds));
        left.push(slot);
      }
    }
    pending = left;
  }
  return maps.map((map, slot) => map ?? fallback(slot, reasons[slot]));
}

/** Where every TPS try failed (landmarks.warp.tps._rigid_map): the least-squares similarity of the landmarks
 * (targets, sources: `count` rows), else the identity, on the grid. */
function rigidGridMap(targets: Float64Array, sources: Float64Array, count: number, grid: CoarseGrid,
                      reasons: string[]): GridMap {
  const rows = grid.ys.length, cols = grid.xs.length;
  const matrix = count >= 2 ? fitSimilarity(targets, sources) : null;
  const mapX = new Float64Array(rows * cols), mapY = new Float64Array(rows * cols);
  for (let j = 0, p = 0; j < rows; j++) {
    for (let i = 0; i < cols; i++, p++) {
      const x = grid.xs[i], y = grid.ys[j];
      mapX[p] = matrix ? matrix[0] * x + matrix[1] * y + matrix[2] : x;
      mapY[p] = matrix ? matrix[3] * x + matrix[4] * y + matrix[5] : y;
    }
  }
  const why = matrix ? reasons : [...reasons, "no similarity: landmarks have no spread"];
  return { mapX, mapY, method: matrix ? "similarity" : "identity", regularization: 0, foldedFraction: 0,
           reason: why.join("; "), grid };
}

/** Why a try was rejected: its map folds (landmarks.warp.tps._folded_reason). */
function foldedReason(lambda: number, folds: number): string {
  return `lambda ${formatG(lambda)}: ${(folds * 100).toFixed(2)}% of pixels folded`;
}

function dense(map: GridMap): WarpMap {
  const { grid, mapX, mapY, ...rest } = map;
  return { ...rest, mapX: densifyGrid(grid, mapX), mapY: densifyGrid(grid, mapY) };
}

/** The dense backward map of the warp moving sourcePoints onto targetPoints (landmarks.warp.tps.tps_map). */
export function tpsMap(sourcePoints: Tensor, targetPoints: Tensor, height: number, width: number,
                       settings: TpsSettings = {}): WarpMap {
  return dense(tpsGridMap(sourcePoints, targetPoints, height, width, settings));
}

/** tps_map of several source point sets onto one target, sharing the merge, one solve and the kernel on the grid
 * (landmarks.warp.tps.tps_maps): the same tries and fallbacks (gridTries), those that fold going on together, one
 * solve per try; a set with other missing points than the target's goes through tpsMap alone. */
export function tpsMaps(sourceSets: Tensor[], targetPoints: Tensor, height: number, width: number,
                        settings: TpsSettings = {}): WarpMap[] {
  return tpsGridMaps(sourceSets, targetPoints, height, width, settings).map(dense);
}

/** tpsMaps on the grid, not yet dense. */
export function tpsGridMaps(sourceSets: Tensor[], targetPoints: Tensor, height: number, width: number,
                     settings: TpsSettings = {}): GridMap[] {
  const o = options(settings);
  const maps: (GridMap | null)[] = sourceSets.map(() => null);
  const targetOk = targetPoints.shape.length === 2 && targetPoints.shape[1] === 2;
  const found = targetOk ? finiteRows(targetPoints) : [];
  const shared = targetOk ? sourceSets.flatMap((points, index) => {
    if (points.shape.length !== 2 || points.shape[0] !== targetPoints.shape[0] || points.shape[1] !== 2) return [];
    const rows = finiteRows(points);
    return covers(rows, found) ? [index] : [];
  }) : [];
  if (shared.length > 0) {
    const columns = 2 * shared.length, rows = indicesWhere(found);
    const fixed = o.fixBorder ? borderPoints(height, width) : [];
    const sets = shared.map((index) => sourceSets[index]);
    const [control, values] = mergeClosePoints(...controlPoints(targetPoints, sets, rows, fixed), columns,
                                               o.mergeDistance);
    const grid = coarseGrid(height, width, o.gridStep);
    const got = gridTries(control, values, shared.length, grid, o, (slot, reasons) => {
      const [targets, sources] = controlPoints(targetPoints, [sets[slot]], rows, []);
      return rigidGridMap(targets, sources, rows.length, grid, reasons);
    });
    shared.forEach((index, slot) => { maps[index] = got[slot]; });
  }
  return maps.map((map, index) => map ?? tpsGridMap(sourceSets[index], targetPoints, height, width, o));
}

/** (H, W) float32 in {0, 1}: the map samples inside the source image (landmarks.warp.tps.WarpMap.valid). */
export function warpValidMask(map: Pick<WarpMap, "mapX" | "mapY">, sourceHeight: number, sourceWidth: number,
                              out?: Float32Array): Float32Array {
  const f = Math.fround, slack = 1e-3;  // numpy compares the float32 maps with float32 bounds
  const low = f(-slack), right = f(sourceWidth - 1 + slack), bottom = f(sourceHeight - 1 + slack);
  const { mapX, mapY } = map, mask = out ?? new Float32Array(mapX.length), count = mask.length;
  for (let i = 0; i < count; i++) {
    const x = mapX[i], y = mapY[i];
    mask[i] = x >= low && x <= right && y >= low && y <= bottom ? 1 : 0;
  }
  return mask;
}
