// Masks drawn and measured as the Python has OpenCV do it, ported to give the same pixels: cv2.fillConvexPoly and
// the filled cv2.ellipse (imgproc/src/drawing.cpp: FillConvexPoly, ellipse2Poly, Line, Line2, clipLine;
// 8-connected, in 1/65536-pixel fixed point), cv2.fillPoly with LINE_AA (LineAA, CollectPolyEdges,
// FillEdgeCollection), cv2.convexHull of integer points, and cv2.distanceTransform (DIST_L2, 3x3 chamfer). Used by
// composite.ts (landmarks/scene/compositing.py: the head ellipses, the face's hull, its feather and its colour band)
// and mouth.ts (polygonMask's anti-aliased polygons).

import { roundHalfEven as rint } from "./remap.js";
import { ascending } from "./tensor.js";

const f32 = Math.fround;

// ---- drawing.cpp: filled ellipses and convex polygons, 8-connected ------------------------------------------

const XY_SHIFT = 16, XY_ONE = 1 << XY_SHIFT;
const SIN_TABLE = Float32Array.from({ length: 451 }, (_, i) => Number(Math.sin((i * Math.PI) / 180).toFixed(7)));
const shr = (value: number, bits: number) => Math.floor(value / 2 ** bits);  // int64 >> bits

/** Pixel (x, y) of a (height, width) mask set to 1 where it lies in the mask (Line's put). Module functions here, not
 * closures made per line, which V8 compiled again on every frame. */
function setPixel(img: Uint8Array, width: number, height: number, x: number, y: number): void {
  if (x >= 0 && x < width && y >= 0 && y < height) img[y * width + x] = 1;
}

/** Pixel `at` of a mask moved toward `color` by a/256 twice (LineAA's anti-aliased put). */
function blendPixel(img: Uint8Array, at: number, color: number, a: number): void {
  let v = img[at];
  v += ((color - v) * a + 127) >> 8;
  v += ((color - v) * a + 127) >> 8;
  img[at] = v & 0xff;
}

/** LineAA's end-point correction at `scount` steps from the line's start and `ecount` from its end (ep: its 3 x 3
 * table). */
function endCorrection(ep: Int32Array | number[], scount: number, ecount: number): number {
  return ep[((+(scount >= 2) + 1) & (scount | 2)) * 3 + ((+(ecount >= 2) + 1) & (ecount | 2))];
}

/** Which of an image's sides (x, y) lies beyond: clipLine's region code. */
function outCode(x: number, y: number, right: number, bottom: number): number {
  return (x < 0 ? 1 : 0) + (x > right ? 2 : 0) + (y < 0 ? 4 : 0) + (y > bottom ? 8 : 0);
}

/** clipLine on an (width, height) image, int64 arithmetic: clips p = [x1, y1, x2, y2] in place; false if outside. */
function clipLine(width: number, height: number, p: number[]): boolean {
  if (width <= 0 || height <= 0) return false;
  const right = width - 1, bottom = height - 1;
  let c1 = outCode(p[0], p[1], right, bottom), c2 = outCode(p[2], p[3], right, bottom);
  if ((c1 & c2) === 0 && (c1 | c2) !== 0) {
    if (c1 & 12) {
      const a = c1 < 8 ? 0 : bottom;
      p[0] += Math.trunc(((a - p[1]) * (p[2] - p[0])) / (p[3] - p[1]));
      p[1] = a;
      c1 = (p[0] < 0 ? 1 : 0) + (p[0] > right ? 2 : 0);
    }
    if (c2 & 12) {
      const a = c2 < 8 ? 0 : bottom;
      p[2] += Math.trunc(((a - p[3]) * (p[2] - p[0])) / (p[3] - p[1]));
      p[3] = a;
      c2 = (p[2] < 0 ? 1 : 0) + (p[2] > right ? 2 : 0);
    }
    if ((c1 & c2) === 0 && (c1 | c2) !== 0) {
      if (c1) {
        const a = c1 === 1 ? 0 : right;
        p[1] += Math.trunc(((a - p[0]) * (p[3] - p[1])) / (p[2] - p[0]));
        p[0] = a;
        c1 = 0;
      }
      if (c2) {
        const a = c2 === 1 ? 0 : right;
        p[3] += Math.trunc(((a - p[2]) * (p[3] - p[1])) / (p[2] - p[0]));
        p[2] = a;
        c2 = 0;
      }
    }
  }
  return (c1 | c2) === 0;
}

/** Line (LineIterator, 8-connected, left to right) of integer points. */
function line(img: Uint8Array, width: number, height: number, x1: number, y1: number, x2: number, y2: number): void {
  if (x1 < 0 || x1 >= width || x2 < 0 || x2 >= width || y1 < 0 || y1 >= height || y2 < 0 || y2 >= height) {
    const p = [x1, y1, x2, y2];
    if (!clipLine(width, height, p)) return;
    [x1, y1, x2, y2] = p;
  }
  let dx = x2 - x1, dy = y2 - y1;
  if (dx < 0) { dx = -dx; dy = -dy; x1 = x2; y1 = y2; }
  const sy = dy < 0 ? -1 : 1;
  dy = Math.abs(dy);
  const steep = dy > dx;
  if (steep) [dx, dy] = [dy, dx];
  let err = dx - 2 * dy, x = x1, y = y1;
  for (let i = 0; i <= dx; i++) {
    img[y * width + x] = 1;
    const minor = err < 0;
    err += -2 * dy + (minor ? 2 * dx : 0);
    if (steep) { y += sy; if (minor) x += 1; } else { x += 1; if (minor) y += sy; }
  }
}

/** Line2: a line between points in 1/65536 pixels. */
function line2(img: Uint8Array, width: number, height: number, p1x: number, p1y: number, p2x: number, p2y: number
               ): void {
  const p = [p1x, p1y, p2x, p2y];
  if (!clipLine(width * XY_ONE, height * XY_ONE, p)) return;
  let [x1, y1, x2, y2] = p;
  const dx0 = x2 - x1, dy0 = y2 - y1, ax = Math.abs(dx0), ay = Math.abs(dy0);
  let xStep: number, yStep: number, ecount: number;
  if (ax > ay) {
    const dy = dx0 < 0 ? -dy0 : dy0;
    if (dx0 < 0) [x1, y1, x2, y2] = [x2, y2, x1, y1];
    xStep = XY_ONE;
    yStep = Math.trunc((dy * XY_ONE) / (ax | 1));
    ecount = shr(x2 - x1, XY_SHIFT);
  } else {
    const dx = dy0 < 0 ? -dx0 : dx0;
    if (dy0 < 0) [x1, y1, x2, y2] = [x2, y2, x1, y1];
    xStep = Math.trunc((dx * XY_ONE) / (ay | 1));
    yStep = XY_ONE;
    ecount = shr(y2 - y1, XY_SHIFT);
  }
  x1 += XY_ONE >> 1;
  y1 += XY_ONE >> 1;
  setPixel(img, width, height, shr(x2 + (XY_ONE >> 1), XY_SHIFT), shr(y2 + (XY_ONE >> 1), XY_SHIFT));
  if (ax > ay) {
    x1 = shr(x1, XY_SHIFT);
    for (; ecount >= 0; ecount--, x1++, y1 += yStep) setPixel(img, width, height, x1, shr(y1, XY_SHIFT));
  } else {
    y1 = shr(y1, XY_SHIFT);
    for (; ecount >= 0; ecount--, x1 += xStep, y1++) setPixel(img, width, height, shr(x1, XY_SHIFT), y1);
  }
}

/** FillConvexPoly (LINE_8): vertices (x, y) in 1/2^shift pixels, value 1. */
export function fillConvexPoly(img: Uint8Array, width: number, height: number, v: number[][], shift: number): void {
  const npts = v.length, delta = shift ? 1 << (shift - 1) : 0, half = XY_ONE >> 1, up = 2 ** (XY_SHIFT - shift);
  let p0 = [v[npts - 1][0] * up, v[npts - 1][1] * up];
  let xmin = v[0][0], xmax = v[0][0], ymin = v[0][1], ymax = v[0][1], imin = 0;
  for (let i = 0; i < npts; i++) {
    const [px, py] = v[i];
    if (py < ymin) { ymin = py; imin = i; }
    ymax = Math.max(ymax, py); xmax = Math.max(xmax, px); xmin = Math.min(xmin, px);
    const p = [px * up, py * up];
    if (shift === 0) line(img, width, height, p0[0] / XY_ONE, p0[1] / XY_ONE, p[0] / XY_ONE, p[1] / XY_ONE);
    else line2(img, width, height, p0[0], p0[1], p[0], p[1]);
    p0 = p;
  }
  xmin = shr(xmin + delta, shift); xmax = shr(xmax + delta, shift);
  ymin = shr(ymin + delta, shift); ymax = shr(ymax + delta, shift);
  if (npts < 3 || xmax < 0 || ymax < 0 || xmin >= width || ymin >= height) return;
  ymax = Math.min(ymax, height - 1);
  const edge = [{ idx: imin, di: 1, x: -XY_ONE, dx: 0, ye: ymin },
                { idx: imin, di: npts - 1, x: -XY_ONE, dx: 0, ye: ymin }];
  let edges = npts, y = ymin;
  do {
    for (const e of edge) {
      if (y < e.ye) continue;
      let idx0 = e.idx, idx = idx0 + e.di;
      if (idx >= npts) idx -= npts;
      for (; edges-- > 0;) {
        const ty = shr(v[idx][1] + delta, shift);
        if (ty > y) {
          const xs = v[idx0][0] * up, xe = v[idx][0] * up;
          e.ye = ty;
          e.dx = Math.trunc(((xe - xs) * 2 + (ty - y)) / (2 * (ty - y)));
          e.x = xs;
          e.idx = idx;
          break;
        }
        idx0 = idx;
        idx += e.di;
        if (idx >= npts) idx -= npts;
      }
    }
    if (edges < 0) break;
    if (y >= 0) {
      const [left, right] = edge[0].x > edge[1].x ? [edge[1], edge[0]] : [edge[0], edge[1]];
      let xx1 = shr(left.x + half, XY_SHIFT), xx2 = shr(right.x + half, XY_SHIFT);
      if (xx2 >= 0 && xx1 < width) {
        xx1 = Math.max(xx1, 0);
        xx2 = Math.min(xx2, width - 1);
        img.fill(1, y * width + xx1, y * width + xx2 + 1);
      }
    }
    edge[0].x += edge[0].dx;
    edge[1].x += edge[1].dx;
  } while (++y <= ymax);
}

/** cv2.ellipse(mask, centre, axes, 0, 0, 360, 1, -1, cv2.LINE_8, shift=4) (centre, axes in 1/16 pixels). */
export function fillEllipse(img: Uint8Array, width: number, height: number, cx16: number, cy16: number, ax16: number,
                     ay16: number): void {
  const up = 2 ** (XY_SHIFT - 4), cx = cx16 * up, cy = cy16 * up, aw = Math.abs(ax16 * up), ah = Math.abs(ay16 * up);
  let delta = shr(Math.max(aw, ah) + (XY_ONE >> 1), XY_SHIFT);
  delta = delta < 3 ? 90 : delta < 10 ? 30 : delta < 15 ? 18 : 5;
  const points: number[][] = [];
  for (let i = 0; i < 360 + delta; i += delta) {
    const angle = Math.min(i, 360);
    const rounded = [cx + aw * SIN_TABLE[450 - angle], cy + ah * SIN_TABLE[angle]].map((value) => {
      const high = rint(value / XY_ONE) * XY_ONE;
      return high + rint(value - high);
    });
    const last = points[points.length - 1];
    if (!last || last[0] !== rounded[0] || last[1] !== rounded[1]) points.push(rounded);
  }
  if (points.length === 1) points.splice(0, 1, [cx, cy], [cx, cy]);
  fillConvexPoly(img, width, height, points, XY_SHIFT);
}

// ---- drawing.cpp: cv2.fillPoly with LINE_AA, 1 channel ------------------------------------------------------

const SLOPE_CORR = [181, 181, 181, 182, 182, 183, 184, 185, 187, 188, 190, 192, 194, 196, 198, 201,
  203, 206, 209, 211, 214, 218, 221, 224, 227, 231, 235, 238, 242, 246, 250, 254];
const FILTER_TABLE = [168, 177, 185, 194, 202, 210, 218, 224, 231, 236, 241, 246, 249, 252, 254, 254,
  254, 254, 252, 249, 246, 241, 236, 231, 224, 218, 210, 202, 194, 185, 177, 168,
  158, 149, 140, 131, 122, 114, 105, 97, 89, 82, 75, 68, 62, 56, 50, 45,
  40, 36, 32, 28, 25, 22, 19, 16, 14, 12, 11, 9, 8, 7, 5, 5];

/** cv::LineAA on a 1-channel uint8 image: points in XY_SHIFT fixed point. */
function lineAA(img: Uint8Array, width: number, height: number, p: number[], color: number): void {
  if (!clipLine(width * XY_ONE, height * XY_ONE, p)) return;
  let [x1, y1, x2, y2] = p;
  let dx = x2 - x1, dy = y2 - y1;
  const ax = Math.abs(dx), ay = Math.abs(dy);
  let xStep: number, yStep: number, ecount: number, slope: number, i: number, j: number;
  if (ax > ay) {
    if (dx < 0) { dy = -dy; [x1, x2] = [x2, x1]; [y1, y2] = [y2, y1]; }
    xStep = XY_ONE;
    yStep = Math.trunc((dy * XY_ONE) / (ax % 2 === 1 ? ax : ax + 1));
    x2 += XY_ONE;
    ecount = shr(x2, XY_SHIFT) - shr(x1, XY_SHIFT);
    const frac = -(x1 & (XY_ONE - 1));
    y1 += shr(yStep * frac, XY_SHIFT) + (XY_ONE >> 1);
    slope = (yStep >> (XY_SHIFT - 5)) & 0x3f;
    slope ^= yStep < 0 ? 0x3f : 0;
    i = (x1 >> (XY_SHIFT - 7)) & 0x78;
    j = (x2 >> (XY_SHIFT - 7)) & 0x78;
  } else {
    if (dy < 0) { dx = -dx; [x1, x2] = [x2, x1]; [y1, y2] = [y2, y1]; }
    xStep = Math.trunc((dx * XY_ONE) / (ay % 2 === 1 ? ay : ay + 1));
    yStep = XY_ONE;
    y2 += XY_ONE;
    ecount = shr(y2, XY_SHIFT) - shr(y1, XY_SHIFT);
    const frac = -(y1 & (XY_ONE - 1));
    x1 += shr(xStep * frac, XY_SHIFT) + (XY_ONE >> 1);
    slope = (xStep >> (XY_SHIFT - 5)) & 0x3f;
    slope ^= xStep < 0 ? 0x3f : 0;
    i = (y1 >> (XY_SHIFT - 7)) & 0x78;
    j = (y2 >> (XY_SHIFT - 7)) & 0x78;
  }
  slope = slope & 0x20 ? 0x100 : SLOPE_CORR[slope];
  const t0 = slope << 7, t1 = ((0x78 - i) | 4) * slope, t2 = (j | 4) * slope;
  const ep = [0, 0, 0, 0, 0, 0, 0, 0, slope];
  ep[1] = ep[3] = (((((j - i) & 0x78) | 4) * slope) >> 8) & 0x1ff;
  ep[2] = (t1 >> 8) & 0x1ff;
  ep[4] = (((((j - i) + 0x80) | 4) * slope) >> 8) & 0x1ff;
  ep[5] = ((t1 + t0) >> 8) & 0x1ff;
  ep[6] = (t2 >> 8) & 0x1ff;
  ep[7] = ((t2 + t0) >> 8) & 0x1ff;
  let scount = 0;
  if (ax > ay) {
    for (let x = shr(x1, XY_SHIFT); ecount >= 0; x++, y1 += yStep, scount++, ecount--) {
      if (x < 0 || x >= width) continue;
      const y = shr(y1, XY_SHIFT) - 1, epCorr = endCorrection(ep, scount, ecount), dist = (y1 >> (XY_SHIFT - 5)) & 31;
      if (y >= 0 && y < height) blendPixel(img, y * width + x, color, ((epCorr * FILTER_TABLE[dist + 32]) >> 8) & 0xff);
      if (y + 1 >= 0 && y + 1 < height) blendPixel(img, (y + 1) * width + x, color, ((epCorr * FILTER_TABLE[dist]) >> 8) & 0xff);
      if (y + 2 >= 0 && y + 2 < height) blendPixel(img, (y + 2) * width + x, color, ((epCorr * FILTER_TABLE[63 - dist]) >> 8) & 0xff);
    }
  } else {
    for (let y = shr(y1, XY_SHIFT); ecount >= 0; y++, x1 += xStep, scount++, ecount--) {
      if (y < 0 || y >= height) continue;
      const x = shr(x1, XY_SHIFT) - 1, epCorr = endCorrection(ep, scount, ecount), dist = (x1 >> (XY_SHIFT - 5)) & 31;
      if (x >= 0 && x < width) blendPixel(img, y * width + x, color, ((epCorr * FILTER_TABLE[dist + 32]) >> 8) & 0xff);
      if (x + 1 >= 0 && x + 1 < width) blendPixel(img, y * width + x + 1, color, ((epCorr * FILTER_TABLE[dist]) >> 8) & 0xff);
      if (x + 2 >= 0 && x + 2 < width) blendPixel(img, y * width + x + 2, color, ((epCorr * FILTER_TABLE[63 - dist]) >> 8) & 0xff);
    }
  }
}

interface PolyEdge { y0: number; y1: number; x: number; dx: number }

/** cv2.fillPoly(img, [points], color, cv2.LINE_AA, shift) on a 1-channel uint8 image: the anti-aliased outline
 * (CollectPolyEdges' LineAA per edge), then the scan-line fill of the interior (FillEdgeCollection).
 * points: flat (x, y) integers in 1/2^shift pixels. */
export function fillPolyAA(img: Uint8Array, width: number, height: number, points: Int32Array, color: number,
                           shift: number): void {
  const count = points.length / 2, delta = (1 << shift) >> 1, up = 2 ** (XY_SHIFT - shift), down = 2 ** shift;
  const edges: PolyEdge[] = [];
  let x0 = points[2 * count - 2] * up, y0 = Math.floor((points[2 * count - 1] + delta) / down);
  for (let k = 0; k < count; k++) {
    const x1 = points[2 * k] * up, y1 = Math.floor((points[2 * k + 1] + delta) / down);
    lineAA(img, width, height, [x0, y0 * XY_ONE, x1, y1 * XY_ONE], color);
    if (y0 !== y1) {
      const dx = Math.trunc((x1 - x0) / (y1 - y0));
      edges.push(y0 < y1 ? { y0, y1, x: x0, dx } : { y0: y1, y1: y0, x: x1, dx });
    }
    x0 = x1;
    y0 = y1;
  }
  if (edges.length < 2) return;
  let yMin = Infinity, yMax = -Infinity, xMin = Infinity, xMax = -Infinity;
  for (const e of edges) {
    const xEnd = e.x + (e.y1 - e.y0) * e.dx;
    yMin = Math.min(yMin, e.y0); yMax = Math.max(yMax, e.y1);
    xMin = Math.min(xMin, e.x, xEnd); xMax = Math.max(xMax, e.x, xEnd);
  }
  if (yMax < 0 || yMin >= height || xMax < 0 || xMin >= width * XY_ONE) return;
  yMax = Math.min(yMax, height);
  // Each scan line fills between consecutive pairs of the edges crossing it (y0 <= y < y1), ordered by their x there:
  // FillEdgeCollection's active-edge list, whose x advance by dx per line.
  const xs: number[] = [];
  for (let y = yMin; y < yMax; y++) {
    xs.length = 0;
    for (const e of edges) if (e.y0 <= y && y < e.y1) xs.push(e.x + (y - e.y0) * e.dx);
    if (y < 0) continue;
    xs.sort(ascending);
    for (let k = 0; k + 1 < xs.length; k += 2) {
      let left = shr(xs[k] + XY_ONE - 1, XY_SHIFT), right = shr(xs[k + 1], XY_SHIFT);
      if (left < width && right >= 0) {
        left = Math.max(left, 0);
        right = Math.min(right, width - 1);
        img.fill(color, y * width + left, y * width + right + 1);
      }
    }
  }
}

const byXThenY = (a: number[], b: number[]) => a[0] - b[0] || a[1] - b[1];
const cross = (o: number[], a: number[], b: number[]) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);

/** cv2.convexHull of integer points (flat x, y): the hull's vertices, no collinear ones. */
export function convexHull(points: number[]): number[][] {
  const pts: number[][] = [];
  for (let i = 0; i < points.length; i += 2) pts.push([points[i], points[i + 1]]);
  pts.sort(byXThenY);
  if (pts.length < 3) return pts;
  const lower: number[][] = [], upper: number[][] = [];
  for (const p of pts) {
    while (lower.length >= 2 && cross(lower[lower.length - 2], lower[lower.length - 1], p) <= 0) lower.pop();
    lower.push(p);
  }
  for (let i = pts.length - 1; i >= 0; i--) {
    const p = pts[i];
    while (upper.length >= 2 && cross(upper[upper.length - 2], upper[upper.length - 1], p) <= 0) upper.pop();
    upper.push(p);
  }
  return [...lower.slice(0, -1), ...upper.slice(0, -1)];
}

// ---- distance transform (imgproc/src/distransform.cpp) ------------------------------------------------------

/** cv2.distanceTransform(mask, cv2.DIST_L2, 3): for each nonzero pixel its 3x3-chamfer distance (0.955, 1.3693) to
 * the nearest zero pixel; (h, w) float32. */
export function distanceTransform(mask: Uint8Array, width: number, height: number, inverted: boolean): Float32Array {
  const a = f32(0.955), b = f32(1.3693), far = 32768, stride = width + 2;
  const t = new Float64Array((height + 2) * stride).fill(far);
  for (let y = 0; y < height; y++) {
    for (let x = 0, i = (y + 1) * stride + 1; x < width; x++, i++) {
      if ((mask[y * width + x] !== 0) === inverted) { t[i] = 0; continue; }
      t[i] = Math.min(t[i - stride - 1] + b, t[i - stride] + a, t[i - stride + 1] + b, t[i - 1] + a, far);
    }
  }
  const out = new Float32Array(width * height);
  for (let y = height - 1; y >= 0; y--) {
    for (let x = width - 1, i = (y + 1) * stride + width; x >= 0; x--, i--) {
      let d = t[i];
      if (d > a) d = t[i] = Math.min(d, t[i + stride + 1] + b, t[i + stride] + a, t[i + stride - 1] + b, t[i + 1] + a);
      out[y * width + x] = d;
    }
  }
  return out;
}
