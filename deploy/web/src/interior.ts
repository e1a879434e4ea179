// The inside of an open mouth from the driver's own frame: landmarks/parts/mouth/interior.py (cut_driver_mouth,
// interior_strength, lip_affine, paste_interior), as the live session finishes a frame with mouth_interior "driver".
// The driver's frame around its lips is cut where the frame is (the tracker's worker, or this thread), mapped onto
// the target by the affine fit of the target's 20 lip points to the driver's (bicubic, as cv2.warpAffine with
// WARP_INVERSE_MAP), lit as the target is (matchLight: no more colourful than the skin around the lips, then the
// brightness and, away from its highlights, half the colour cast of the target's nose against the driver's:
// noseLight), and laid inside the target's inner lips.

import { pointBox, polygonMask } from "./mouth.js";
import { estimateHeadPose } from "./pose.js";
import { dilateEllipse, gaussianBlurF32, roundHalfEven, warpAffineCubic } from "./remap.js";
import { finite, flat, interOcularDistance, mouthOpening } from "./retarget.js";
import { Affine, Tensor, percentile, tensor } from "./tensor.js";

export const OPEN: [number, number] = [0.02, 0.04];
export const REACH = 0.35;
export const RING = 0.12;
export const GAIN: [number, number] = [0.6, 1.6];
export const FEATHER = 0.012;
export const TURN: [number, number] = [35.0, 50.0];
export const CAST = 0.5;
export const FADE = 2.0;
/** The nose as a polygon of the 68 points (the top of its bridge, then its base): the skin whose light the interior
 * takes (interior.NOSE; noseLight). */
export const NOSE = [27, 31, 32, 33, 34, 35];

const f32 = Math.fround;

/** A driver frame's mouth (landmarks.parts.mouth.interior.DriverMouth). */
export interface DriverMouth {
  /** (h, w, 3) uint8 RGB: the driver frame around its lips. */
  patch: Tensor<Uint8Array>;
  /** (20, 2) float64: the driver's lip points (48-67) in the patch's pixels. */
  lips: Tensor<Float64Array>;
  /** The driver's mouth opening. */
  opening: number;
  /** The driver's head yaw in degrees (NaN: not found). */
  yaw: number;
  /** (3,) the driver's mean colour over its nose (noseLight); null (or absent): the skin ring around its lips. */
  light?: Float64Array | null;
}

/** One face's (68, 2) points, flat (an Error for another shape). */
export function checkLandmarks(landmarks: Tensor): ArrayLike<number> {
  if (landmarks.shape.length !== 2 || landmarks.shape[0] !== 68 || landmarks.shape[1] !== 2) {
    throw new Error(`landmarks must be (68, 2), got [${landmarks.shape}]`);
  }
  return landmarks.data;
}

/** cut_around: the frame (H, W, 3) uint8 around the points from..to (exclusive) of flat (x, y) pairs `p`, their box
 * grown by `reach` pixels and clipped to the frame -> the patch (a copy) and its top-left corner, or null when under
 * 2 pixels of the box lie in the frame. */
export function cutAround(frame: Tensor<Uint8Array>, p: ArrayLike<number>, from: number, to: number, reach: number
                          ): { patch: Tensor<Uint8Array>; x0: number; y0: number } | null {
  const [minX, minY, maxX, maxY] = pointBox(p, from, to), [height, width] = frame.shape;
  const x0 = Math.max(Math.floor(minX - reach), 0), y0 = Math.max(Math.floor(minY - reach), 0);
  const x1 = Math.min(Math.ceil(maxX + reach) + 1, width), y1 = Math.min(Math.ceil(maxY + reach) + 1, height);
  if (x1 - x0 < 2 || y1 - y0 < 2) return null;
  const w = x1 - x0, h = y1 - y0, patch = new Uint8Array(w * h * 3);
  for (let y = 0; y < h; y++) patch.set(frame.data.subarray(((y0 + y) * width + x0) * 3, ((y0 + y) * width + x1) * 3), y * w * 3);
  return { patch: tensor(patch, [h, w, 3]), x0, y0 };
}

/** The driver's mouth (cut_driver_mouth): frame (H, W, 3) uint8 and its 68 points (frame pixels) -> the patch
 * around its lips, or null when the points are not finite, the mouth is closed or its box is outside the frame. */
export function cutDriverMouth(frame: Tensor<Uint8Array>, landmarks: Tensor): DriverMouth | null {
  if (frame.shape.length !== 3 || frame.shape[2] !== 3) throw new Error(`frame must be (H, W, 3), got [${frame.shape}]`);
  const p = checkLandmarks(landmarks);
  if (!finite(p)) return null;
  const opening = mouthOpening(p);
  if (!(opening >= OPEN[0])) return null;
  const cut = cutAround(frame, p, 48, 68, REACH * interOcularDistance(p));
  if (cut === null) return null;
  const lips = new Float64Array(40);
  for (let i = 0; i < 20; i++) { lips[2 * i] = p[2 * (48 + i)] - cut.x0; lips[2 * i + 1] = p[2 * (48 + i) + 1] - cut.y0; }
  const yaw = estimateHeadPose(landmarks, frame.shape[0], frame.shape[1])[0];
  return { patch: cut.patch, lips: tensor(lips, [20, 2]), opening, yaw, light: noseLight(frame, p) };
}

/** nose_light: the mean colour of `image` (H, W, 3) uint8 inside the nose polygon (NOSE) of the (68, 2) points `p`
 * (flat, its pixels), or null where it covers no pixel. */
export function noseLight(image: Tensor, p: ArrayLike<number>): Float64Array | null {
  const nose = new Float64Array(2 * NOSE.length);
  NOSE.forEach((point, i) => { nose[2 * i] = p[2 * point]; nose[2 * i + 1] = p[2 * point + 1]; });
  const cut = cutAround(image as Tensor<Uint8Array>, nose, 0, NOSE.length, 2.0);
  if (cut === null) return null;
  const [h, w] = cut.patch.shape, inside = polygonMask(nose, 0, NOSE.length, cut.x0, cut.y0, w, h);
  const sum = [0, 0, 0];
  let count = 0;
  for (let k = 0; k < w * h; k++) {
    if (inside[k] < 128) continue;  // coverage / 255 > 0.5
    for (let c = 0; c < 3; c++) sum[c] += cut.patch.data[3 * k + c];
    count++;
  }
  return count ? Float64Array.of(sum[0] / count, sum[1] / count, sum[2] / count) : null;
}

/** interior_strength: the lesser opening of the target's (68, 2) points and the driver's, OPEN[0] -> 0, OPEN[1] -> 1,
 * less as the driver's head turns from TURN[0] to TURN[1] degrees (none where its yaw is unknown). */
export function interiorStrength(landmarks: Tensor, mouth: DriverMouth): number {
  const opening = Math.min(mouthOpening(landmarks.data), mouth.opening);
  if (!Number.isFinite(opening) || !Number.isFinite(mouth.yaw)) return 0;
  const opened = Math.min(Math.max((opening - OPEN[0]) / (OPEN[1] - OPEN[0]), 0), 1);
  return opened * Math.min(Math.max((TURN[1] - Math.abs(mouth.yaw)) / (TURN[1] - TURN[0]), 0), 1);
}

/** The determinant of a 3 x 3 matrix (row-major). */
function det3(m: number[]): number {
  return m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) + m[2] * (m[3] * m[7] - m[4] * m[6]);
}

/** x with a x = b (3 x 3 a, row-major) by Cramer's rule: column i of a replaced by b (b[row] in row `row`). */
function cramer(a: number[], b: number[]): number[] {
  const whole = det3(a), out = [0, 0, 0];
  for (let column = 0; column < 3; column++) {
    const replaced = a.slice();
    for (let k = column; k < 9; k += 3) replaced[k] = b[Math.floor(k / 3)];
    out[column] = det3(replaced) / whole;
  }
  return out;
}

/** lip_affine: the affine map [a, b, c, d, e, f] (x' = a x + b y + c, y' = d x + e y + f) taking the points
 * `from` onto `to` ((N, 2) or flat (x, y) pairs) in least squares, by the normal equations. */
export function lipAffine(from: Tensor | ArrayLike<number>, to: Tensor | ArrayLike<number>): Affine {
  const source = flat(from), target = flat(to), n = source.length / 2, ata = [0, 0, 0, 0, 0, 0, 0, 0, 0], atx = [0, 0, 0], aty = [0, 0, 0];
  for (let i = 0; i < n; i++) {
    const row = [source[2 * i], source[2 * i + 1], 1];
    for (let r = 0; r < 3; r++) {
      for (let c = 0; c < 3; c++) ata[3 * r + c] += row[r] * row[c];
      atx[r] += row[r] * target[2 * i];
      aty[r] += row[r] * target[2 * i + 1];
    }
  }
  return [...cramer(ata, atx), ...cramer(ata, aty)] as Affine;
}

/** The length of pixel k's colour ((h, w, 3) float32 `values`): its channels less their mean, as colourScale sums it.
 * A function of its own, not a closure made per call (V8 optimised such closures again on every frame). */
function colourLength(values: Float32Array, k: number): number {
  const mean = f32(f32(f32(values[3 * k] + values[3 * k + 1]) + values[3 * k + 2]) / 3);
  const d0 = f32(values[3 * k] - mean), d1 = f32(values[3 * k + 1] - mean), d2 = f32(values[3 * k + 2] - mean);
  return Math.sqrt(d0 * d0 + d1 * d1 + d2 * d2);
}

/** colour_ratio and desaturated: [`warped` ((h, w, 3) float32) with each pixel's colour (its channels less their
 * mean) scaled by the target's colourfulness over the patch's (the mean length of that colour over the skin, `grown`
 * less `lips`), at most 1, and that ratio]; `warped` itself and 1 where the target is as colourful or more. */
function colourScale(warped: Float32Array, region: Float32Array, grown: Uint8Array, lips: Uint8Array, w: number,
                     h: number): [Float32Array, number] {
  let target = 0, driven = 0, skin = 0;
  for (let k = 0; k < w * h; k++) {
    if (!grown[k] || lips[k]) continue;
    target += colourLength(region, k); driven += colourLength(warped, k); skin++;
  }
  if (!skin || !(driven > 0) || target >= driven) return [warped, 1];
  const keep = f32(1 - f32(target / driven)), result = new Float32Array(warped.length);
  for (let k = 0; k < w * h; k++) {
    const mean = f32(f32(f32(warped[3 * k] + warped[3 * k + 1]) + warped[3 * k + 2]) / 3);
    for (let c = 0; c < 3; c++) result[3 * k + c] = f32(warped[3 * k + c] - f32(keep * f32(warped[3 * k + c] - mean)));
  }
  return [result, target / driven];
}

/** match_light: the driver's mapped patch `warped` ((h, w, 3) float32) lit as the target is, against `region`, the
 * synthesis there, whose outer lips cover `lips` ((h, w) 0/1) with a skin ring `ring` pixels wide around them: one
 * gain for the ring's brightness (clipped to GAIN), then `cast` of the rings' colour-cast difference, fading out
 * toward the synthesis' brightest there (`fade`; null: no fading, skin laid on skin); the patch as it is where
 * there is no ring. colourful false: another person's patch, first made no more colourful than the target
 * (colourScale). lights: the target's and the patch's mean colours over skin elsewhere (the noses': noseLight), in
 * place of the rings'. */
export function matchLight(warped: Float32Array, region: Float32Array, lips: Uint8Array, w: number, h: number,
                           ring: number, cast = CAST, fade: number | null = FADE, colourful = true,
                           lights: [ArrayLike<number>, ArrayLike<number>] | null = null): Float32Array {
  const grown = dilateEllipse(lips, w, h, ring);
  const lit = lights === null ? null : lights.map((light) => Array.from(light));
  if (!colourful) {
    const [scaled, scale] = colourScale(warped, region, grown, lips, w, h);
    warped = scaled;
    if (lit !== null) {  // the driver's light as colourless as its patch now is
      const grey = (lit[1][0] + lit[1][1] + lit[1][2]) / 3;
      lit[1] = lit[1].map((v) => v - (1 - scale) * (v - grey));
    }
  }
  const means = [[0, 0, 0], [0, 0, 0]], brightest: number[] = [];
  let skin = 0;
  for (let k = 0; k < w * h; k++) {
    if (!grown[k]) continue;
    brightest.push(Math.max(region[3 * k], region[3 * k + 1], region[3 * k + 2]));
    if (lips[k]) continue;
    for (let c = 0; c < 3; c++) { means[0][c] += region[3 * k + c]; means[1][c] += warped[3 * k + c]; }
    skin++;
  }
  if (!skin) return warped;
  const [target, driven] = lit ?? means.map((m) => m.map((v) => v / skin));
  const grey = [target, driven].map((m) => (m[0] + m[1] + m[2]) / 3);
  const gain = Math.min(Math.max((grey[0] + 1) / (grey[1] + 1), GAIN[0]), GAIN[1]), g = f32(gain);
  const shift = [0, 1, 2].map((c) => f32(((target[c] - grey[0]) - gain * (driven[c] - grey[1])) * cast));
  const top = f32(Math.max(percentile(Float32Array.from(brightest), 99.0), 1));
  const result = new Float32Array(warped.length);
  for (let k = 0; k < w * h; k++) {
    for (let c = 0; c < 3; c++) result[3 * k + c] = f32(warped[3 * k + c] * g);
    const mean = f32(f32(f32(result[3 * k] + result[3 * k + 1]) + result[3 * k + 2]) / 3);
    const fading = fade === null ? 1 : Math.min(Math.max(f32(fade * f32(1 - f32(mean / top))), 0), 1);
    for (let c = 0; c < 3; c++) result[3 * k + c] = f32(result[3 * k + c] + f32(fading * shift[c]));
  }
  return result;
}

/** paste_interior: `image` (S, S, 3) uint8, the synthesis for the target's (68, 2) points, with the driver's mouth
 * interior inside the target's inner lips; `image` itself when there is nothing to lay in, else a new image (or
 * `image` written in place when inPlace). */
export function pasteInterior(image: Tensor, landmarks: Tensor, mouth: DriverMouth | null, inPlace = false): Tensor {
  if (image.shape.length !== 3 || image.shape[2] !== 3 || !(image.data instanceof Uint8Array)) {
    throw new Error(`image must be (H, W, 3) uint8, got [${image.shape}]`);
  }
  const p = checkLandmarks(landmarks);
  const strength = mouth === null || !finite(p) ? 0 : interiorStrength(landmarks, mouth);
  if (!(strength > 0)) return image;
  const eyes = interOcularDistance(p), ring = Math.max(1, roundHalfEven(RING * eyes));
  const sigma = Math.max(0.4, FEATHER * eyes), margin = ring + Math.ceil(3 * sigma) + 1;
  const [height, width] = image.shape, [minX, minY, maxX, maxY] = pointBox(p, 48, 68);
  const x0 = Math.max(Math.floor(minX) - margin, 0), y0 = Math.max(Math.floor(minY) - margin, 0);
  const x1 = Math.min(Math.ceil(maxX) + margin + 1, width), y1 = Math.min(Math.ceil(maxY) + margin + 1, height);
  if (x1 - x0 < 2 || y1 - y0 < 2) return image;
  const w = x1 - x0, h = y1 - y0, local = new Float64Array(40);
  for (let i = 0; i < 20; i++) { local[2 * i] = p[2 * (48 + i)] - x0; local[2 * i + 1] = p[2 * (48 + i) + 1] - y0; }
  const [ph, pw] = mouth!.patch.shape;
  const warped = warpAffineCubic({ data: mouth!.patch.data, width: pw, height: ph, channels: 3 },
                                 lipAffine(local, mouth!.lips.data), w, h, "replicate");
  const source = image.data as Uint8Array;
  const lipArea = polygonMask(local, 0, 12, 0, 0, w, h);
  for (let i = 0; i < lipArea.length; i++) lipArea[i] = lipArea[i] >= 128 ? 1 : 0;  // coverage / 255 > 0.5
  const region = new Float32Array(w * h * 3), mapped = new Float32Array(w * h * 3);
  for (let y = 0; y < h; y++) {
    region.set(source.subarray(3 * ((y0 + y) * width + x0), 3 * ((y0 + y) * width + x1)), 3 * y * w);
  }
  for (let i = 0; i < mapped.length; i++) mapped[i] = warped[i];
  const targetLight = mouth!.light ? noseLight(image, p) : null;
  const laid = matchLight(mapped, region, lipArea, w, h, ring, CAST, FADE, false,
                          targetLight === null ? null : [targetLight, mouth!.light!]);
  const inner = polygonMask(local, 12, 20, 0, 0, w, h), unit = f32(1.0 / 255.0), coverage = new Float32Array(w * h);
  for (let i = 0; i < coverage.length; i++) coverage[i] = f32(inner[i] * unit);
  const weight = gaussianBlurF32(coverage, w, h, 1, sigma), s = f32(strength);
  const out = inPlace ? image : tensor(new Uint8Array(source), [...image.shape]);
  const data = out.data as Uint8Array;
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const k = y * w + x, wt = f32(weight[k] * s), rest = f32(1.0 - wt), at = 3 * ((y0 + y) * width + x0 + x);
      for (let c = 0; c < 3; c++) {
        const mixed = f32(f32(wt * laid[3 * k + c]) + f32(rest * source[at + c]));
        data[at + c] = Math.min(Math.max(roundHalfEven(mixed), 0), 255);
      }
    }
  }
  return out;
}
