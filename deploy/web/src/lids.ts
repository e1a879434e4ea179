// The subject's own lids drawn down where the target shuts its eyes: landmarks/parts/eyes/drawn_lids.py (shot_lid_gaps,
// lid_strength, lash_line, lid_normal, draw_lids), as the live session finishes a frame with lids "drawn", or
// "driver" where the camera gave no shut eyes to lay in. Between the eye as the shots show it open (the target's
// lids at the shots' gaps, grown) and the drawn lid's margin (the target's upper lid lowered by the strength), the
// skin around is filled in (segment.ts fillIn), darkened along the margin by a lash line, feathered and faded in.
// The module's GROW, LASH, DARK, FEATHER, RAMP, REACH and LIFT are LID_GROW ... LID_LIFT here.

import { SHUT, apertureShare } from "./eyes.js";
import { polygonMask } from "./mouth.js";
import { dilateEllipse, gaussianBlurF32, roundHalfEven } from "./remap.js";
import { finite, flat, interOcularDistance, lidGaps, setLidGaps } from "./retarget.js";
import { fillIn } from "./segment.js";
import { Tensor, median, tensor } from "./tensor.js";

export const LID_GROW = 0.04;
export const LID_LASH = 0.06;
export const LID_DARK = 0.5;
export const LID_FEATHER = 0.02;
export const LID_RAMP = 2.0;
export const LID_REACH = 0.5;
export const LID_LIFT = 0.5;
/** Each eye's first of the 68 points: six each, the corners first and fourth. */
const EYE_STARTS = [36, 42];

const f32 = Math.fround;

/** shot_lid_gaps: the subject's lids at rest, the median lidGaps of its shots' (K, 68, 2) points (NaN ignored). */
export function shotLidGaps(shotLandmarks: Tensor): Float64Array {
  const count = shotLandmarks.shape[0], data = flat(shotLandmarks), out = new Float64Array(2);
  const per = Array.from({ length: count }, (_, k) => lidGaps(Array.prototype.slice.call(data, 136 * k, 136 * (k + 1))));
  for (let e = 0; e < 2; e++) out[e] = median(per.map((g) => g[e]).filter((v) => !Number.isNaN(v)));
  return out;
}

/** lid_strength: none from an aperture share of SHUT[1] against the subject's lids at rest, wholly from SHUT[0]
 * down (0 where not finite). */
export function lidStrength(landmarks: Tensor | ArrayLike<number>, referenceGaps: Tensor | ArrayLike<number>): number {
  const share = apertureShare(landmarks, referenceGaps);
  return Number.isFinite(share) ? Math.min(Math.max((SHUT[1] - share) / (SHUT[1] - SHUT[0]), 0), 1) : 0;
}

/** lash_line: exp(-d^2 / 2 sigma^2) of each pixel's distance d to the polyline (flat x, y), (h, w) float32. */
export function lashLine(polyline: Tensor | ArrayLike<number>, sigma: number, h: number, w: number): Float32Array {
  const points = flat(polyline), out = new Float32Array(w * h), count = points.length / 2;
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      let nearest = Infinity;
      for (let k = 0; k + 1 < count; k++) {
        const ax = points[2 * k], ay = points[2 * k + 1], dx = points[2 * k + 2] - ax, dy = points[2 * k + 3] - ay;
        const t = Math.min(Math.max(((x - ax) * dx + (y - ay) * dy) / Math.max(dx * dx + dy * dy, 1e-12), 0), 1);
        const ex = x - ax - t * dx, ey = y - ay - t * dy;
        nearest = Math.min(nearest, ex * ex + ey * ey);
      }
      out[y * w + x] = Math.exp(-nearest / (2.0 * sigma * sigma));
    }
  }
  return out;
}

/** lid_normal: the unit normal of an eye's corner line toward its lower lid; eye: 6 points, flat. */
function lidNormal(eye: ArrayLike<number>): [number, number] {
  const ax = eye[6] - eye[0], ay = eye[7] - eye[1], length = Math.max(Math.hypot(ax, ay), 1e-12);
  const nx = -ay / length, ny = ax / length;
  const lowerX = (eye[8] + eye[10]) / 2 - (eye[0] + eye[6]) / 2, lowerY = (eye[9] + eye[11]) / 2 - (eye[1] + eye[7]) / 2;
  return nx * lowerX + ny * lowerY >= 0 ? [nx, ny] : [-nx, -ny];
}

/** draw_lids: `image` (S, S, 3) uint8, the synthesis for the target's (68, 2) points, with the subject's upper lids
 * drawn down where the points shut them against its lids at rest (2,); `which`: the eyes drawn (image left first);
 * `image` itself when nothing shuts, else a new image (or `image` written in place when inPlace). */
export function drawLids(image: Tensor, landmarks: Tensor, referenceGaps: Tensor | ArrayLike<number>,
                         inPlace = false, which: [boolean, boolean] = [true, true]): Tensor {
  if (image.shape.length !== 3 || image.shape[2] !== 3 || !(image.data instanceof Uint8Array)) {
    throw new Error(`image must be (H, W, 3) uint8, got [${image.shape}]`);
  }
  const p = flat(landmarks), reference = flat(referenceGaps);
  const strength = lidStrength(p, reference);
  if (!(strength > 0) || !(which[0] || which[1])) return image;
  const gaps = lidGaps(p), points = tensor(Float64Array.from(p), [68, 2]);
  const fmax = (a: number, b: number) => (Number.isNaN(a) ? b : Number.isNaN(b) ? a : Math.max(a, b));
  const opened = setLidGaps(points, [fmax(reference[0], gaps[0]), fmax(reference[1], gaps[1])]).data;
  const margin = setLidGaps(points, [gaps[0] * (1 - strength), gaps[1] * (1 - strength)]).data;
  const scale = interOcularDistance(p), alpha = f32(Math.min(1, LID_RAMP * strength));
  const [height, width] = image.shape, source = image.data as Uint8Array;
  const work = Float32Array.from(source);
  const grow = Math.max(1, roundHalfEven(LID_GROW * scale)), inv255 = f32(1.0 / 255.0), dark = f32(LID_DARK);
  for (const [eye, start] of EYE_STARTS.entries()) {
    if (!which[eye]) continue;
    const cx = (p[2 * start] + p[2 * start + 6]) / 2, cy = (p[2 * start + 1] + p[2 * start + 7]) / 2;
    const x0 = Math.max(0, Math.floor(cx - LID_REACH * scale)), y0 = Math.max(0, Math.floor(cy - LID_REACH * scale));
    const x1 = Math.min(width, Math.ceil(cx + LID_REACH * scale)), y1 = Math.min(height, Math.ceil(cy + LID_REACH * scale));
    if (x1 - x0 < 2 || y1 - y0 < 2 || !finite(opened.subarray(2 * start, 2 * start + 12))) continue;
    const w = x1 - x0, h = y1 - y0;
    const open = dilateEllipse(polygonMask(opened, start, start + 6, x0, y0, w, h, 4), w, h, grow);
    const kept = polygonMask(margin, start, start + 6, x0, y0, w, h, 4);
    const hole = new Float32Array(w * h), known = new Float32Array(w * h), patch = new Float32Array(w * h * 3);
    for (let k = 0; k < w * h; k++) {
      hole[k] = f32(f32(open[k] * inv255) * f32(1.0 - f32(kept[k] * inv255)));
      known[k] = f32(1.0 - hole[k]);
    }
    for (let y = 0; y < h; y++) patch.set(work.subarray(3 * ((y0 + y) * width + x0), 3 * ((y0 + y) * width + x1)), 3 * y * w);
    const filled = fillIn(tensor(patch, [h, w, 3]), tensor(known, [h, w])).data;
    const sigma = Math.max(0.5, 0.6 * LID_LASH * scale);
    const [nx, ny] = lidNormal(Array.prototype.slice.call(p, 2 * start, 2 * start + 12));
    const lid = [0, 1, 2, 3].flatMap((i) => [margin[2 * (start + i)] - x0, margin[2 * (start + i) + 1] - y0]);
    for (const i of [1, 2]) {
      lid[2 * i] -= LID_LIFT * sigma * nx;
      lid[2 * i + 1] -= LID_LIFT * sigma * ny;
    }
    const line = lashLine(lid, sigma, h, w), cover = new Float32Array(w * h);
    for (let k = 0; k < w * h; k++) cover[k] = Math.max(hole[k], line[k]);
    const weight = gaussianBlurF32(cover, w, h, 1, Math.max(0.5, LID_FEATHER * scale));
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        const k = y * w + x, shade = f32(1.0 - f32(dark * line[k])), wt = f32(weight[k] * alpha);
        for (let c = 0; c < 3; c++) {
          const at = 3 * ((y0 + y) * width + x0 + x), before = patch[3 * k + c];
          const drawn = f32(filled[3 * k + c] * shade);
          work[at + c] = f32(before + f32(f32(drawn - before) * wt));
        }
      }
    }
  }
  const out = inPlace ? image : tensor(new Uint8Array(source.length), [...image.shape]);
  const data = out.data as Uint8Array;
  for (let i = 0; i < work.length; i++) data[i] = Math.min(Math.max(Math.floor(f32(work[i] + 0.5)), 0), 255);
  return out;
}
