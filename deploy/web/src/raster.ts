// The landmark image the network is conditioned on: the 68 points as coloured open polylines on black
// (landmarks/shape/raster.py draw_landmarks: the LSR release's contour images, 2.78 px per 224 px wide, parts in order,
// later on top). Drawn here from each part's distance field (round joins, projecting end caps, a one-pixel
// anti-aliased edge) instead of OpenCV's anti-aliased quads: the pictures differ only along the strokes' edges, and
// the frame generator's output moves by less than 1/500 of a grey level's worth of PSNR (55 dB apart on the bundled
// pair), far inside the 40 dB the browser's parity with the Python runtime asks.

import { Tensor, checkPoints, tensor } from "./tensor.js";

/** [first, stop) of each part (landmarks/shape/ibug68.py PARTS), in drawing order, with its colour (matplotlib's). */
export const PARTS: [number, number, [number, number, number]][] = [
  [0, 17, [0, 128, 0]], // jaw: green
  [17, 22, [255, 165, 0]], // brows: orange
  [22, 27, [255, 165, 0]],
  [27, 31, [0, 0, 255]], // nose bridge and base: blue
  [31, 36, [0, 0, 255]],
  [36, 42, [255, 0, 0]], // eyes: red
  [42, 48, [255, 0, 0]],
  [48, 60, [128, 0, 128]], // outer lips: purple
  [60, 68, [255, 192, 203]], // inner lips: pink
];
export const REFERENCE_STROKE_PX = (2.0 * 100.0) / 72.0; // matplotlib lw 2 pt at 100 dpi, at 224 px
export const REFERENCE_SIZE = 224;
export const MIN_STROKE_PX = 1.5;

/** Draw (68, 2) points, already in the image's pixels, into a size x size RGB landmark image (uint8). Points that
 * are not finite give a black image, as in Python. */
export function drawLandmarks(points: Tensor, size: number, thickness?: number): Tensor<Uint8Array> {
  const out = new Float32Array(size * size * 3);
  const image = new Uint8Array(size * size * 3);
  if (points.shape[0] !== 68 || points.shape[1] !== 2) checkPoints(points, 68, "landmarks");
  for (const value of points.data) if (!Number.isFinite(value)) return tensor(image, [size, size, 3]);
  // OpenCV's anti-aliased strokes never ink less than about 1.5 px across (landmarks/shape/raster.py): neither do these
  const half = Math.max(thickness ?? (REFERENCE_STROKE_PX * size) / REFERENCE_SIZE, MIN_STROKE_PX) / 2;
  const distance = new Float32Array(size * size);
  for (const [first, stop, colour] of PARTS) {
    distance.fill(Infinity);
    let x0 = size, y0 = size, x1 = -1, y1 = -1;
    for (let i = first; i < stop - 1; i++) {
      let ax = points.data[2 * i], ay = points.data[2 * i + 1];
      let bx = points.data[2 * i + 2], by = points.data[2 * i + 3];
      const length = Math.hypot(bx - ax, by - ay);
      if (length > 1e-9) { // projecting caps: the open polyline's ends reach half a width further
        const ux = (bx - ax) / length, uy = (by - ay) / length;
        if (i === first) { ax -= ux * half; ay -= uy * half; }
        if (i === stop - 2) { bx += ux * half; by += uy * half; }
      }
      const dx = bx - ax, dy = by - ay, squared = dx * dx + dy * dy;
      const reach = half + 1;
      const left = Math.max(0, Math.floor(Math.min(ax, bx) - reach)), right = Math.min(size - 1, Math.ceil(Math.max(ax, bx) + reach));
      const top = Math.max(0, Math.floor(Math.min(ay, by) - reach)), bottom = Math.min(size - 1, Math.ceil(Math.max(ay, by) + reach));
      for (let y = top; y <= bottom; y++) {
        for (let x = left; x <= right; x++) {
          let t = squared > 1e-18 ? ((x - ax) * dx + (y - ay) * dy) / squared : 0;
          t = t < 0 ? 0 : t > 1 ? 1 : t;
          const d = Math.hypot(x - ax - t * dx, y - ay - t * dy);
          const index = y * size + x;
          if (d < distance[index]) distance[index] = d;
        }
      }
      x0 = Math.min(x0, left); y0 = Math.min(y0, top); x1 = Math.max(x1, right); y1 = Math.max(y1, bottom);
    }
    for (let y = y0; y <= y1; y++) {
      for (let x = x0; x <= x1; x++) {
        const index = y * size + x;
        const cover = Math.min(1, Math.max(0, half + 0.5 - distance[index]));
        if (cover <= 0) continue;
        for (let c = 0; c < 3; c++) out[3 * index + c] += (colour[c] - out[3 * index + c]) * cover;
      }
    }
  }
  for (let i = 0; i < out.length; i++) image[i] = Math.round(out[i]);
  return tensor(image, [size, size, 3]);
}
