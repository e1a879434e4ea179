// Samplers as the Python references call them from OpenCV: cv2.remap / cv2.warpAffine with INTER_CUBIC on uint8 and
// INTER_LINEAR on float32 (OpenCV 5 samples both at the exact float position with float weights, rounded to nearest),
// cv2.resize (INTER_AREA to shrink, INTER_LINEAR to enlarge, float32), cv2.GaussianBlur (float32), the border rules
// (cv2.borderInterpolate), and the coarse grids smooth maps are made on, then densified bilinearly
// (landmarks.warp.tps._Grid). Used by tps.ts (landmarks/warp/tps.py: _remap, _Grid) and composite.ts (landmarks/scene/compositing.py).

import { blurInWasm } from "./blur_wasm.js";
import { Affine, Tensor, tensor } from "./tensor.js";

export type BorderMode = "constant" | "replicate" | "reflect" | "reflect101";

/** Where index p of a row of `length` reads from under a border rule; -1 for a constant border
 * (cv2.borderInterpolate). */
export function borderIndex(p: number, length: number, border: BorderMode): number {
  if (p >= 0 && p < length) return p;
  if (border === "replicate") return p < 0 ? 0 : length - 1;
  if (border === "constant") return -1;
  if (length === 1) return 0;
  const delta = border === "reflect101" ? 1 : 0;
  do { p = p < 0 ? -p - 1 + delta : length - 1 - (p - length) - delta; } while (p < 0 || p >= length);
  return p;
}

/** Round half to even, as cvRound (and numpy's rint / Python's round) do. */
export function roundHalfEven(value: number): number {
  const rounded = Math.round(value);
  return rounded - value === 0.5 && rounded % 2 !== 0 ? rounded - 1 : rounded;
}

// ---- bicubic (OpenCV 5: float weights at the exact float position, Keys' a = -0.75) -------------------------
// In float32: each weight, product and sum rounded to float32 in the order below, as remap_wasm.ts's kernel does it
// with a pixel's three channels in the lanes of one float32x4 (the same bytes). Sums in float64 would give a value
// one grey level apart about twice in 100,000; OpenCV's differ from either as rarely.

const f = Math.fround;

/** Keys' cubic weights (a = -0.75) of the 4 taps around a sample at fraction t in [0, 1), in float32, into
 * w[o..o+3]. */
function cubicWeights(t: number, w: Float32Array, o: number): void {
  const A = -0.75, u = f(1 - t), p = f(t + 1);
  w[o] = f(f(f(f(f(f(A * p) - 5 * A) * p) + 8 * A) * p) - 4 * A);
  w[o + 1] = f(f(f(f(f((A + 2) * t) - (A + 3)) * t) * t) + 1);
  w[o + 2] = f(f(f(f(f((A + 2) * u) - (A + 3)) * u) * u) + 1);
  w[o + 3] = f(f(f(1 - w[o]) - w[o + 1]) - w[o + 2]);
}

const weights = new Float32Array(8);

/** A uint8 array's bytes as a Uint8ClampedArray: a number stored there is rounded half to even and saturated to
 * [0, 255] (ECMAScript's ToUint8Clamp; NaN gives 0), as cvRound + saturate_cast<uchar> do, and far faster than
 * Math.round and a tie check. */
export function clampedView(array: Uint8Array): Uint8ClampedArray {
  return new Uint8ClampedArray(array.buffer, array.byteOffset, array.length);
}

/** One row's four taps (a, b, c, d) under the weights of x, in float32. */
function taps(a: number, b: number, c: number, d: number, w0: number, w1: number, w2: number, w3: number): number {
  return f(f(f(f(a * w0) + f(b * w1)) + f(c * w2)) + f(d * w3));
}

/** cubicAt for 3 channels at (x, y) whose 4 x 4 taps (from (ix - 1, iy - 1)) lie inside the image: the usual case.
 * x, y: float32 values; dst: the output's clamped view (rounds and saturates). */
function cubicInside3(src: Uint8Array, stride: number, x: number, y: number, ix: number, iy: number,
                      dst: Uint8ClampedArray, o: number): void {
  const w = weights;
  cubicWeights(x - ix, w, 0);
  cubicWeights(y - iy, w, 4);
  const w0 = w[0], w1 = w[1], w2 = w[2], w3 = w[3], h0 = w[4], h1 = w[5], h2 = w[6], h3 = w[7];
  const a = (iy - 1) * stride + (ix - 1) * 3, b = a + stride, c = b + stride, d = c + stride;
  for (let k = 0; k < 3; k++) {
    const ak = a + k, bk = b + k, ck = c + k, dk = d + k;
    const r0 = taps(src[ak], src[ak + 3], src[ak + 6], src[ak + 9], w0, w1, w2, w3);
    const r1 = taps(src[bk], src[bk + 3], src[bk + 6], src[bk + 9], w0, w1, w2, w3);
    const r2 = taps(src[ck], src[ck + 3], src[ck + 6], src[ck + 9], w0, w1, w2, w3);
    const r3 = taps(src[dk], src[dk + 3], src[dk + 6], src[dk + 9], w0, w1, w2, w3);
    dst[o + k] = f(f(f(f(r0 * h0) + f(r1 * h1)) + f(r2 * h2)) + f(r3 * h3));
  }
}

/** One output pixel of OpenCV's bicubic at source (x, y): its `channels` values, rounded and saturated (dst: the
 * output's clamped view), to dst[dstOffset...]. A constant border reads 0. */
function cubicAt(src: Uint8Array, width: number, height: number, channels: number, x: number, y: number,
                 border: BorderMode, dst: Uint8ClampedArray, dstOffset: number): void {
  if (!(Math.abs(x) < 1e7 && Math.abs(y) < 1e7)) {  // far off (or NaN): only the border is read
    x = Math.max(-1e7, Math.min(1e7, x || 0));
    y = Math.max(-1e7, Math.min(1e7, y || 0));
  }
  const ix = Math.floor(x), iy = Math.floor(y), sx = ix - 1, sy = iy - 1, stride = width * channels;
  const w = weights;
  cubicWeights(f(x - ix), w, 0);
  cubicWeights(f(y - iy), w, 4);
  if (border === "constant" && (sx >= width || sx + 4 <= 0 || sy >= height || sy + 4 <= 0)) {
    for (let k = 0; k < channels; k++) dst[dstOffset + k] = 0;
    return;
  }
  const inside = sx >= 0 && sx < width - 3 && sy >= 0 && sy < height - 3;
  const x0 = inside ? sx : borderIndex(sx, width, border), x1 = inside ? sx + 1 : borderIndex(sx + 1, width, border);
  const x2 = inside ? sx + 2 : borderIndex(sx + 2, width, border);
  const x3 = inside ? sx + 3 : borderIndex(sx + 3, width, border);
  for (let k = 0; k < channels; k++) {
    let sum = 0;
    for (let r = 0; r < 4; r++) {
      const yr = inside ? sy + r : borderIndex(sy + r, height, border), row = yr * stride + k;
      const product = yr < 0 ? 0 : f(w[4 + r] * taps(
        x0 >= 0 ? src[row + x0 * channels] : 0, x1 >= 0 ? src[row + x1 * channels] : 0,
        x2 >= 0 ? src[row + x2 * channels] : 0, x3 >= 0 ? src[row + x3 * channels] : 0, w[0], w[1], w[2], w[3]));
      sum = r === 0 ? product : f(sum + product);
    }
    dst[dstOffset + k] = sum;
  }
}

/** A source image: (height, width, channels) row-major. */
export interface PixelImage<T> { data: T; width: number; height: number; channels: number }

/** cv2.remap(src, mapX, mapY, cv2.INTER_CUBIC, borderMode=border) for uint8: output pixel i samples the source at
 * (mapX[i], mapY[i]). only: when given, the pixels where it is 0 are left as dst has them. dst: (mapX.length *
 * channels) values, made when not given. */
export function remapCubic(src: PixelImage<Uint8Array>, mapX: Float32Array, mapY: Float32Array, border: BorderMode,
                           dst?: Uint8Array, only?: Uint8Array): Uint8Array {
  const channels = src.channels;
  const out = dst ?? new Uint8Array(mapX.length * channels), clamped = clampedView(out);
  const { data, width, height } = src, stride = width * channels, fast = channels === 3;
  const xEnd = width - 2, yEnd = height - 2, count = mapX.length;
  for (let i = 0; i < count; i++) {
    if (only && !only[i]) continue;
    const x = mapX[i], y = mapY[i];
    // floor(x) in [1, width - 3] exactly when x is in [1, width - 2) (false for NaN): then x | 0 is its floor
    if (fast && x >= 1 && x < xEnd && y >= 1 && y < yEnd) cubicInside3(data, stride, x, y, x | 0, y | 0, clamped, 3 * i);
    else cubicAt(data, width, height, channels, x, y, border, clamped, i * channels);
  }
  return out;
}

/** remapCubic's pixels `listed` (the first `count` indices), those whose taps leave the source (remap_wasm.ts lists
 * them and leaves them to this). */
export function remapCubicListed(src: PixelImage<Uint8Array>, mapX: Float32Array, mapY: Float32Array,
                                 border: BorderMode, dst: Uint8Array, listed: Int32Array, count: number): void {
  const { data, width, height, channels } = src, clamped = clampedView(dst);
  for (let k = 0; k < count; k++) {
    const i = listed[k];
    cubicAt(data, width, height, channels, mapX[i], mapY[i], border, clamped, i * channels);
  }
}

/** cv2.warpAffine(src, m, (width, height), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=border) for
 * uint8: output (x, y) samples the source at m (x, y), the position in float32 as OpenCV 5 computes it. */
export function warpAffineCubic(src: PixelImage<Uint8Array>, m: Affine, width: number, height: number,
                                border: BorderMode): Uint8Array {
  const channels = src.channels, m0 = f(m[0]), m3 = f(m[3]);
  const stride = src.width * channels, fast = channels === 3;
  const out = new Uint8Array(width * height * channels), clamped = clampedView(out);
  const uEnd = src.width - 2, vEnd = src.height - 2;
  for (let y = 0; y < height; y++) {
    const mx = f(y * m[1] + m[2]), my = f(y * m[4] + m[5]);
    for (let x = 0; x < width; x++) {
      const u = f(m0 * x + mx), v = f(m3 * x + my);
      if (fast && u >= 1 && u < uEnd && v >= 1 && v < vEnd) {
        cubicInside3(src.data, stride, u, v, u | 0, v | 0, clamped, (y * width + x) * 3);
      } else cubicAt(src.data, src.width, src.height, channels, u, v, border, clamped, (y * width + x) * channels);
    }
  }
  return out;
}

/** The inverse cv2.warpAffine takes of a forward (source -> output) matrix when not given WARP_INVERSE_MAP
 * (imgwarp.cpp warpAffine: 1 / determinant, 0 for a singular one). */
export function openCvInverse(m: Affine): Affine {
  let d = m[0] * m[4] - m[1] * m[3];
  d = d !== 0 ? 1 / d : 0;
  const a = m[4] * d, e = m[0] * d, b = m[1] * -d, c = m[3] * -d;
  return [a, b, -a * m[2] - b * m[5], c, e, -c * m[2] - e * m[5]];
}

/** cv2.warpAffine(src, m, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=border) for
 * uint8 (INTER_AREA too: warpAffine does it as INTER_LINEAR): output (x, y) samples the source at m (x, y), the
 * position in float64 rounded to float32, float32 weights, v0 = p00 + a (p01 - p00), v1 = p10 + a (p11 - p10),
 * v0 + b (v1 - v0), rounded to nearest (OpenCV 5's kernel, warp_kernels.simd.hpp; bit-exact against OpenCV 5.1 on
 * the bank's eye patches). A constant border reads 0. */
export function warpAffineLinear(src: PixelImage<Uint8Array>, m: Affine, width: number, height: number,
                                 border: BorderMode): Uint8Array {
  const { channels, data } = src, stride = src.width * channels;
  const out = new Uint8Array(width * height * channels), clamped = clampedView(out);
  for (let y = 0; y < height; y++) {
    for (let x = 0; x < width; x++) {
      const u = f(m[0] * x + m[1] * y + m[2]), v = f(m[3] * x + m[4] * y + m[5]);
      const ix = Math.floor(u), iy = Math.floor(v), a = f(u - ix), b = f(v - iy), o = (y * width + x) * channels;
      const inside = ix >= 0 && ix < src.width - 1 && iy >= 0 && iy < src.height - 1;
      const c0 = inside ? ix : borderIndex(ix, src.width, border);
      const c1 = inside ? ix + 1 : borderIndex(ix + 1, src.width, border);
      const r0 = inside ? iy : borderIndex(iy, src.height, border);
      const r1 = inside ? iy + 1 : borderIndex(iy + 1, src.height, border);
      for (let c = 0; c < channels; c++) {  // module functions, not closures made per pixel
        const v00 = valueAt(data, stride, channels, c, r0, c0), v01 = valueAt(data, stride, channels, c, r0, c1);
        const v10 = valueAt(data, stride, channels, c, r1, c0), v11 = valueAt(data, stride, channels, c, r1, c1);
        clamped[o + c] = lerp(lerp(v00, v01, a), lerp(v10, v11, a), b);
      }
    }
  }
  return out;
}

/** p + t (q - p) in float32 (warpAffineLinear's interpolation). */
function lerp(p: number, q: number, t: number): number {
  return f(p + f(t * f(q - p)));
}

/** Channel c of pixel (row, column) of `data` (0 for a row or column of -1: a constant border's). */
function valueAt(data: Uint8Array, stride: number, channels: number, c: number, row: number, column: number): number {
  return row < 0 || column < 0 ? 0 : data[row * stride + column * channels + c];
}

/** Bilinear sample of a one-channel float image at (x, y) (cv2.remap / warpAffine INTER_LINEAR on float32); a
 * constant border reads 0. */
export function bilinearAt(src: PixelImage<Float32Array>, x: number, y: number, border: BorderMode): number {
  const x0 = Math.floor(x), y0 = Math.floor(y);
  const a = x - x0, b = y - y0, { width, height, data } = src;
  if (x0 >= 0 && x0 < width - 1 && y0 >= 0 && y0 < height - 1) {
    const r0 = y0 * width + x0, r1 = r0 + width;
    return (data[r0] * (1 - a) + data[r0 + 1] * a) * (1 - b) + (data[r1] * (1 - a) + data[r1 + 1] * a) * b;
  }
  const c0 = borderIndex(x0, width, border), c1 = borderIndex(x0 + 1, width, border);
  const i0 = borderIndex(y0, height, border), i1 = borderIndex(y0 + 1, height, border);
  const r0 = i0 < 0 ? -1 : i0 * width, r1 = i1 < 0 ? -1 : i1 * width;
  const p00 = r0 < 0 || c0 < 0 ? 0 : data[r0 + c0], p01 = r0 < 0 || c1 < 0 ? 0 : data[r0 + c1];
  const p10 = r1 < 0 || c0 < 0 ? 0 : data[r1 + c0], p11 = r1 < 0 || c1 < 0 ? 0 : data[r1 + c1];
  return (p00 * (1 - a) + p01 * a) * (1 - b) + (p10 * (1 - a) + p11 * a) * b;
}

// ---- resize (float32, any channels) -------------------------------------------------------------------------

/** cv2.resize(src, (width, height), interpolation=cv2.INTER_AREA) to shrink a float32 image (resize.cpp:
 * computeResizeAreaTab: each output pixel the area-weighted mean of the source pixels it covers). */
export function resizeArea(src: PixelImage<Float32Array>, width: number, height: number): Float32Array {
  const { channels } = src;
  const xs = areaTable(src.width, width), ys = areaTable(src.height, height);
  const rows = new Float64Array(src.height * width * channels);  // each source row shrunk across
  for (let sy = 0; sy < src.height; sy++) {
    const from = sy * src.width * channels, to = sy * width * channels;
    for (let k = 0; k < xs.count; k++) {
      const di = to + xs.dst[k] * channels, si = from + xs.src[k] * channels, a = xs.alpha[k];
      for (let c = 0; c < channels; c++) rows[di + c] += a * src.data[si + c];
    }
  }
  const out = new Float64Array(height * width * channels), line = width * channels;
  for (let k = 0; k < ys.count; k++) {
    const di = ys.dst[k] * line, si = ys.src[k] * line, b = ys.alpha[k];
    for (let i = 0; i < line; i++) out[di + i] += b * rows[si + i];
  }
  return Float32Array.from(out);
}

function areaTable(sourceSize: number, size: number
                   ): { dst: Int32Array; src: Int32Array; alpha: Float64Array; count: number } {
  const scale = sourceSize / size;
  const dst = new Int32Array(sourceSize * 2 + 2), src = new Int32Array(sourceSize * 2 + 2);
  const alpha = new Float64Array(sourceSize * 2 + 2);
  let k = 0;
  for (let dx = 0; dx < size; dx++) {
    const fsx1 = dx * scale, fsx2 = fsx1 + scale, cell = Math.min(scale, sourceSize - fsx1);
    let sx1 = Math.ceil(fsx1), sx2 = Math.floor(fsx2);
    sx2 = Math.min(sx2, sourceSize - 1);
    sx1 = Math.min(sx1, sx2);
    if (sx1 - fsx1 > 1e-3) { dst[k] = dx; src[k] = sx1 - 1; alpha[k++] = Math.fround((sx1 - fsx1) / cell); }
    for (let sx = sx1; sx < sx2; sx++) { dst[k] = dx; src[k] = sx; alpha[k++] = Math.fround(1 / cell); }
    if (fsx2 - sx2 > 1e-3) {
      dst[k] = dx; src[k] = sx2; alpha[k++] = Math.fround(Math.min(Math.min(fsx2 - sx2, 1), cell) / cell);
    }
  }
  return { dst, src, alpha, count: k };
}

/** cv2.resize(src, (width, height), interpolation=cv2.INTER_LINEAR) of a float32 image (pixel centres aligned,
 * the edge pixels replicated). */
export function resizeLinear(src: PixelImage<Float32Array>, width: number, height: number): Float32Array {
  const { channels, data } = src;
  const [x0, ax] = linearTable(src.width, width), [y0, ay] = linearTable(src.height, height);
  const out = new Float32Array(width * height * channels);
  const line = src.width * channels;
  // each output column's two source columns (element offsets) and weights, the same for every row
  const c0 = new Int32Array(width), c1 = new Int32Array(width), a1 = new Float64Array(width), a0 = new Float64Array(width);
  for (let x = 0; x < width; x++) {
    c0[x] = x0[x] * channels;
    c1[x] = Math.min(x0[x] + 1, src.width - 1) * channels;
    a1[x] = ax[x];
    a0[x] = 1 - ax[x];
  }
  for (let y = 0, o = 0; y < height; y++) {
    const r0 = y0[y] * line, r1 = Math.min(y0[y] + 1, src.height - 1) * line, b = ay[y], b0 = 1 - b;
    for (let x = 0; x < width; x++) {
      const p0 = r0 + c0[x], p1 = r0 + c1[x], q0 = r1 + c0[x], q1 = r1 + c1[x], a = a1[x], na = a0[x];
      for (let c = 0; c < channels; c++, o++) {
        const top = data[p0 + c] * na + data[p1 + c] * a;
        const bottom = data[q0 + c] * na + data[q1 + c] * a;
        out[o] = top * b0 + bottom * b;
      }
    }
  }
  return out;
}

function linearTable(sourceSize: number, size: number): [Int32Array, Float64Array] {
  const scale = sourceSize / size, index = new Int32Array(size), fraction = new Float64Array(size);
  for (let d = 0; d < size; d++) {
    const position = Math.fround((d + 0.5) * scale - 0.5);
    let s = Math.floor(position), a = position - s;
    if (s < 0) { s = 0; a = 0; }
    if (s >= sourceSize - 1) { s = sourceSize - 1; a = 0; }
    index[d] = s;
    fraction[d] = a;
  }
  return [index, fraction];
}

// ---- Gaussian blur (float32, any channels) -----------------------------------------------------------------

/** cv::getGaussianKernel(n, sigma, CV_32F). */
function gaussianKernel(n: number, sigma: number): Float32Array {
  const scale = -0.5 / (sigma * sigma), kernel = new Float32Array(n), values: number[] = [];
  let sum = 0;
  for (let i = 0; i < n; i++) {
    const x = i - (n - 1) * 0.5, t = Math.exp(scale * x * x);
    values.push(t);
    sum += t;
  }
  values.forEach((t, i) => { kernel[i] = t / sum; });
  return kernel;
}

export function reflect101(p: number, length: number): number {
  if (length === 1) return 0;
  while (p < 0 || p >= length) p = p < 0 ? -p : 2 * length - 2 - p;
  return p;
}

/** cv2.GaussianBlur(src, (0, 0), sigma) of an (h, w, channels) float32 image: separable, side round(8 sigma + 1) | 1,
 * reflect-101 border. */
export function gaussianBlurF32(src: Float32Array, width: number, height: number, channels: number, sigma: number
                                ): Float32Array {
  const n = roundHalfEven(sigma * 8 + 1) | 1, kernel = gaussianKernel(n, sigma), anchor = n >> 1;
  const xIndex = new Int32Array(width * n), yIndex = new Int32Array(height * n);
  for (let x = 0; x < width; x++) {
    for (let k = 0; k < n; k++) xIndex[x * n + k] = reflect101(x + k - anchor, width) * channels;
  }
  for (let y = 0; y < height; y++) {
    for (let k = 0; k < n; k++) yIndex[y * n + k] = reflect101(y + k - anchor, height) * width * channels;
  }
  const fast = blurInWasm(src, width, height, channels, kernel, xIndex, yIndex);  // the same values
  if (fast !== null) return fast;
  const rows = new Float32Array(src.length), out = new Float32Array(src.length);
  for (let y = 0; y < height; y++) {
    const row = y * width * channels;
    for (let x = 0; x < width; x++) {
      for (let c = 0; c < channels; c++) {
        let s = 0;
        for (let k = 0; k < n; k++) s += kernel[k] * src[row + xIndex[x * n + k] + c];
        rows[row + x * channels + c] = s;
      }
    }
  }
  const line = width * channels;
  for (let y = 0; y < height; y++) {
    for (let i = 0; i < line; i++) {
      let s = 0;
      for (let k = 0; k < n; k++) s += kernel[k] * rows[yIndex[y * n + k] + i];
      out[y * line + i] = s;
    }
  }
  return out;
}

// ---- coarse grids (landmarks.warp.tps._Grid) ---------------------------------------------------------------------

/** Where a map is evaluated: every pixel (step 1), or every `step` pixels with the last row and column included
 * (landmarks.warp.tps._Grid). points: (rows * cols, 2) flat (x, y), row-major. */
export interface CoarseGrid {
  height: number;
  width: number;
  step: number;
  xs: Float64Array;
  ys: Float64Array;
  points: Float64Array;
}

function axis(size: number, step: number): Float64Array {
  const values: number[] = [];
  for (let v = 0; v < size; v += step) values.push(v);
  if (values[values.length - 1] !== size - 1) values.push(size - 1);
  return Float64Array.from(values);
}

export function coarseGrid(height: number, width: number, step: number): CoarseGrid {
  step = Math.max(1, Math.trunc(step));
  const xs = axis(width, step), ys = axis(height, step);
  const points = new Float64Array(xs.length * ys.length * 2);
  for (let j = 0, p = 0; j < ys.length; j++) {
    for (let i = 0; i < xs.length; i++, p += 2) { points[p] = xs[i]; points[p + 1] = ys[j]; }
  }
  return { height, width, step, xs, ys, points };
}

export interface Interpolation { lower: Int32Array; w0: Float32Array; w1: Float32Array }
const interpolations = new Map<string, Interpolation>();

/** Linear interpolation from samples at `coarse` to 0..size-1, float32 weights
 * (landmarks.warp.tps._interpolation_matrix). */
function interpolation(size: number, coarse: Float64Array): Interpolation {
  const key = `${size}:${coarse.length}:${coarse[1]}`;
  const cached = interpolations.get(key);
  if (cached) return cached;
  const lower = new Int32Array(size), w0 = new Float32Array(size), w1 = new Float32Array(size);
  let upper = 1;
  for (let p = 0; p < size; p++) {
    while (upper < coarse.length - 1 && coarse[upper] <= p) upper++;
    const fraction = (p - coarse[upper - 1]) / (coarse[upper] - coarse[upper - 1]);
    lower[p] = upper - 1;
    w0[p] = 1 - fraction;
    w1[p] = fraction;
  }
  const table = { lower, w0, w1 };
  if (interpolations.size > 16) interpolations.clear();
  interpolations.set(key, table);
  return table;
}

let densifyScratch = new Float32Array(0);  // densifyGrid's rows, kept from call to call

/** densifyGrid's interpolation across: each pixel column's grid column to its left and their float32 weights. */
export function gridAcross(grid: CoarseGrid): Interpolation {
  return interpolation(grid.width, grid.xs);
}

/** densifyGrid's first pass: the values down to every pixel row at the grid's columns, (height, cols) float32 into
 * `out`. */
export function densifyRows(grid: CoarseGrid, values: ArrayLike<number>, out: Float32Array): void {
  const rows = interpolation(grid.height, grid.ys), cols = grid.xs.length;
  for (let y = 0; y < grid.height; y++) {
    const a = rows.lower[y] * cols, b = a + cols, w0 = rows.w0[y], w1 = rows.w1[y];
    for (let j = 0; j < cols; j++) {
      out[y * cols + j] = w0 * Math.fround(values[a + j]) + w1 * Math.fround(values[b + j]);
    }
  }
}

/** Values on the grid (rows, cols) -> (H, W) float32 at every pixel, bilinear, float32 like numpy's two products;
 * into `out` when given. */
export function densifyGrid(grid: CoarseGrid, values: ArrayLike<number>, out?: Float32Array): Float32Array {
  const { height, width } = grid, cols = grid.xs.length;
  const dense = out ?? new Float32Array(height * width);
  if (grid.step === 1) {
    dense.set(values);
    return dense;
  }
  const across = gridAcross(grid);
  if (densifyScratch.length < height * cols) densifyScratch = new Float32Array(height * cols);
  const half = densifyScratch, lower = across.lower, a0 = across.w0, a1 = across.w1;
  densifyRows(grid, values, half);
  for (let y = 0, o = 0; y < height; y++) {
    const line = y * cols;
    for (let x = 0; x < width; x++, o++) {
      const l = line + lower[x];
      dense[o] = a0[x] * half[l] + a1[x] * half[l + 1];
    }
  }
  return dense;
}

// ---- the same on tensors (the Python tests call these against OpenCV) ----------------------------------------

function pixelImage<T extends Uint8Array | Float32Array>(tensor: Tensor<T>): PixelImage<T> {
  return { data: tensor.data, height: tensor.shape[0], width: tensor.shape[1], channels: tensor.shape[2] ?? 1 };
}

/** cv2.remap(src, mapX, mapY, cv2.INTER_CUBIC, borderMode) for (H, W[, C]) uint8 and (h, w) float32 maps. */
export function remapImage(src: Tensor<Uint8Array>, mapX: Tensor<Float32Array>, mapY: Tensor<Float32Array>,
                           border: BorderMode = "replicate"): Tensor<Uint8Array> {
  const out = remapCubic(pixelImage(src), Float32Array.from(mapX.data), Float32Array.from(mapY.data), border);
  return tensor(out, [...mapX.shape, ...src.shape.slice(2)]);
}

/** cv2.warpAffine(src, m, (width, height), cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode) for uint8. */
export function warpAffineImage(src: Tensor<Uint8Array>, m: Affine, width: number, height: number,
                                border: BorderMode = "replicate"): Tensor<Uint8Array> {
  return tensor(warpAffineCubic(pixelImage(src), m, width, height, border), [height, width, ...src.shape.slice(2)]);
}

/** cv2.resize of a (H, W[, C]) float32 image: INTER_AREA ("area", which OpenCV does as linear when enlarging) or
 * INTER_LINEAR ("linear"); the same size is a copy. */
export function resizeImage(src: Tensor<Float32Array>, width: number, height: number, interpolation: "area" | "linear"
                            ): Tensor<Float32Array> {
  const [h, w] = src.shape;
  if (h === height && w === width) return tensor(src.data.slice(), [...src.shape]);
  const image = pixelImage(src);
  const out = interpolation === "area" && (width < w || height < h) ? resizeArea(image, width, height)
    : resizeLinear(image, width, height);
  return tensor(out, [height, width, ...src.shape.slice(2)]);
}

/** cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2r + 1, 2r + 1))), constant (ignored) border. */
export function dilateEllipse(src: Uint8Array, width: number, height: number, r: number): Uint8Array {
  const halfWidths: number[] = []; // per kernel row dy = -r..r, the half width of its run of ones
  const inv = r ? 1.0 / (r * r) : 0;
  for (let dy = -r; dy <= r; dy++) halfWidths.push(roundHalfEven(r * Math.sqrt((r * r - dy * dy) * inv)));
  // rowMax[h][y * width + x]: max of row y over [x - h, x + h], built up from h = 0
  const rowMax: Uint8Array[] = [src];
  for (let h = 1; h <= r; h++) {
    const previous = rowMax[h - 1], next = new Uint8Array(previous);
    for (let y = 0; y < height; y++) {
      const row = y * width;
      for (let x = 0; x < width; x++) {
        let v = next[row + x];
        if (x - h >= 0 && src[row + x - h] > v) v = src[row + x - h];
        if (x + h < width && src[row + x + h] > v) v = src[row + x + h];
        next[row + x] = v;
      }
    }
    rowMax.push(next);
  }
  const out = new Uint8Array(width * height);
  for (let y = 0; y < height; y++) {
    for (let k = 0; k < halfWidths.length; k++) {
      const sy = y + k - r;
      if (sy < 0 || sy >= height) continue;
      const from = rowMax[Math.min(halfWidths[k], r)], row = sy * width, at = y * width;
      for (let x = 0; x < width; x++) if (from[row + x] > out[at + x]) out[at + x] = from[row + x];
    }
  }
  return out;
}
