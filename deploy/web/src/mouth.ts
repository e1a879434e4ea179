// The mouth from the nearest warped shot over the synthesis, as the live session finishes a frame with mouth
// "nearest": lsr/core/finish.py (finish_mouth) and landmarks/parts/mouth/nearest_mouth.py (mouth_weight, mouth_strength, mismatch,
// keep_nearest_mouth). The region's mask is drawn as OpenCV draws it (cv2.fillPoly, LINE_AA, shift 2: shapes.ts's
// fillPolyAA), grown by cv2.dilate with cv2's elliptic element and feathered by cv2.GaussianBlur (float32,
// reflect-101 border); the blend in float32 as numpy computes it.

import { dilateEllipse, gaussianBlurF32, roundHalfEven } from "./remap.js";
import { fillPolyAA } from "./shapes.js";
import { Tensor, ascending, tensor } from "./tensor.js";
import { interOcularDistance, mouthOpening } from "./retarget.js";

export const MOUTH_MARGIN = 0.15;
export const MOUTH_FEATHER = 0.04;
export const MISMATCH: [number, number] = [15.0, 25.0];
export const CLOSED_MOUTH = 0.05;

const f32 = Math.fround;

// ---------------------------------------------------------------------------------------------- polygon masks

/** The box [minX, minY, maxX, maxY] of the points from..to (exclusive) of flat (x, y) pairs. */
export function pointBox(p: ArrayLike<number>, from: number, to: number): [number, number, number, number] {
  let minX = Infinity, minY = Infinity, maxX = -Infinity, maxY = -Infinity;
  for (let i = from; i < to; i++) {
    minX = Math.min(minX, p[2 * i]); maxX = Math.max(maxX, p[2 * i]);
    minY = Math.min(minY, p[2 * i + 1]); maxY = Math.max(maxY, p[2 * i + 1]);
  }
  return [minX, minY, maxX, maxY];
}

/** The polygon of the points from..to (exclusive) of flat (x, y) pairs, less (x0, y0), filled into a w x h uint8
 * mask (255 inside) as cv2.fillPoly(mask, [np.round(points * 2**shift)], 255, cv2.LINE_AA, shift) fills it. */
export function polygonMask(p: ArrayLike<number>, from: number, to: number, x0: number, y0: number, w: number,
                            h: number, shift = 2): Uint8Array {
  const mask = new Uint8Array(w * h), polygon = new Int32Array(2 * (to - from)), one = 1 << shift;
  for (let i = from; i < to; i++) {
    polygon[2 * (i - from)] = roundHalfEven((p[2 * i] - x0) * one);
    polygon[2 * (i - from) + 1] = roundHalfEven((p[2 * i + 1] - y0) * one);
  }
  fillPolyAA(mask, w, h, polygon, 255, shift);
  return mask;
}

// ---------------------------------------------------------------------------------------------- nearest mouth

/** The mouth region's weight over its box (landmarks.parts.mouth.nearest_mouth.mouth_weight). */
export interface MouthRegion {
  /** (y1 - y0, x1 - x0) float32 in [0, 1]. */
  weight: Tensor<Float32Array>;
  /** [x0, y0, x1, y1] in the image's pixels. */
  box: [number, number, number, number];
}

/** The mouth region: the target's outer-lip polygon grown by MOUTH_MARGIN and feathered by MOUTH_FEATHER (of its
 * eye distance) over its bounding box (landmarks.parts.mouth.nearest_mouth.mouth_weight). landmarks (68, 2) pixels of an image
 * height x width -> the region, or null when the landmarks are not finite or the region lies outside the image. */
export function mouthWeight(landmarks: Tensor, height: number, width: number): MouthRegion | null {
  const p = landmarks.data;
  if (landmarks.shape.length !== 2 || landmarks.shape[0] !== 68 || landmarks.shape[1] !== 2) {
    throw new Error(`landmarks must be (68, 2), got [${landmarks.shape}]`);
  }
  for (const value of p) if (!Number.isFinite(value)) return null;
  const eyes = interOcularDistance(p);
  const grow = Math.max(1, roundHalfEven(MOUTH_MARGIN * eyes)), sigma = Math.max(0.5, MOUTH_FEATHER * eyes);
  const reach = grow + Math.ceil(3 * sigma) + 1;
  const [minX, minY, maxX, maxY] = pointBox(p, 48, 60);
  const x0 = Math.max(Math.floor(minX) - reach, 0), y0 = Math.max(Math.floor(minY) - reach, 0);
  const x1 = Math.min(Math.ceil(maxX) + reach + 1, width), y1 = Math.min(Math.ceil(maxY) + reach + 1, height);
  if (x1 <= x0 || y1 <= y0) return null;
  const w = x1 - x0, h = y1 - y0, mask = polygonMask(p, 48, 60, x0, y0, w, h);
  const grown = dilateEllipse(mask, w, h, grow), scaled = new Float32Array(w * h), unit = f32(1.0 / 255.0);
  for (let i = 0; i < scaled.length; i++) scaled[i] = grown[i] * unit;
  return { weight: tensor(gaussianBlurF32(scaled, w, h, 1, sigma), [h, w]), box: [x0, y0, x1, y1] };
}

function checkImage(image: Tensor, name: string): [number, number] {
  if (image.shape.length !== 3 || image.shape[2] !== 3 || !(image.data instanceof Uint8Array)) {
    throw new Error(`${name} must be (S, S, 3) uint8, got [${image.shape}]`);
  }
  return [image.shape[0], image.shape[1]];
}

/** Indices of the `count` shots nearest the target (landmarks.warp.tps.nearest_shots: mean point distance over the
 * target's eye-centre distance, ties by index, shots without a face last), repeated to `count` (np.resize). */
function nearestShots(shotLandmarks: Tensor, target: ArrayLike<number>, count: number): number[] {
  const k = shotLandmarks.shape[0], s = shotLandmarks.data, eyes = interOcularDistance(target);
  const distances: number[] = [];
  for (let shot = 0; shot < k; shot++) {
    let sum = 0;
    for (let i = 0; i < 68; i++) {
      const dx = s[shot * 136 + 2 * i] - target[2 * i], dy = s[shot * 136 + 2 * i + 1] - target[2 * i + 1];
      sum += Math.sqrt(dx * dx + dy * dy);
    }
    const d = eyes > 0 ? sum / 68 / eyes : NaN;
    distances.push(Number.isNaN(d) ? Infinity : d);
  }
  const order = distances.map((_, i) => i).sort((a, b) => distances[a] - distances[b] || a - b);
  const chosen = order.slice(0, Math.max(1, Math.min(count, k)));
  return Array.from({ length: count }, (_, i) => chosen[i % chosen.length]);
}

/** How much of the nearest shot's mouth to take (landmarks.parts.mouth.nearest_mouth.mouth_strength): (the target's mouth
 * opening - the median of the references' shots') / CLOSED_MOUTH, clipped to [0, 1] (0 when not finite).
 * landmarks (68, 2); shotLandmarks (K, 68, 2), the same pixels; indices: the shots the references came from (the
 * warp's, nearest first), or a count to choose them here as the warp does. */
export function mouthStrength(landmarks: Tensor, shotLandmarks: Tensor, indices: Tensor | ArrayLike<number> | number
                              ): number {
  const chosen = typeof indices === "number" ? nearestShots(shotLandmarks, landmarks.data, indices)
    : Array.from("shape" in indices ? indices.data : indices);
  const openings = chosen.map((i) => mouthOpening(shotLandmarks.data.subarray(i * 136, (i + 1) * 136)));
  let median: number;
  if (openings.some(Number.isNaN)) median = NaN;
  else {
    openings.sort(ascending);
    const h = openings.length >> 1;
    median = openings.length % 2 ? openings[h] : (openings[h - 1] + openings[h]) / 2;
  }
  const excess = mouthOpening(landmarks.data) - median;
  return Number.isFinite(excess) ? Math.min(Math.max(excess / CLOSED_MOUTH, 0), 1) : 0;
}

/** How unlike the synthesis the nearest shot is around the mouth: the mean absolute difference in grey levels over
 * the region's feathered edge (weight 0.02-0.5) where the shot's warp is valid (landmarks.parts.mouth.nearest_mouth.mismatch). */
function mismatch(image: ArrayLike<number>, nearest: ArrayLike<number>, valid: ArrayLike<number>, width: number,
                  region: MouthRegion): number {
  const [x0, y0, x1, y1] = region.box, w = x1 - x0, weight = region.weight.data;
  let sum = 0, count = 0;
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      const v = weight[(y - y0) * w + (x - x0)], at = y * width + x;
      if (!(v > 0.02 && v < 0.5 && valid[at] > 0.5)) continue;
      const d = Math.abs(nearest[3 * at] - image[3 * at]) + Math.abs(nearest[3 * at + 1] - image[3 * at + 1]) +
        Math.abs(nearest[3 * at + 2] - image[3 * at + 2]);
      sum += f32(d / 3);
      count++;
    }
  }
  return count ? sum / count : 0.0;
}

/** `image` with the mouth region taken from `nearest` where its warp is valid, at `strength`, less where the shot is
 * unlike the synthesis around the mouth (landmarks.parts.mouth.nearest_mouth.keep_nearest_mouth). image, nearest: (S, S, 3)
 * uint8 data; nearestValid: (S, S) in [0, 1]; landmarks: (68, 2) target pixels. Returns `image` itself when nothing
 * is taken, else a new image (or `image` written in place when inPlace). */
export function keepNearestMouth(image: Tensor, nearest: Uint8Array, nearestValid: ArrayLike<number>, landmarks: Tensor,
                                 strength = 1.0, inPlace = false): Tensor {
  const [height, width] = checkImage(image, "image");
  if (nearest.length !== image.data.length) throw new Error("image and nearest must have the same shape");
  const region = strength > 0 ? mouthWeight(landmarks, height, width) : null;
  if (region === null) return image;
  const [low, high] = MISMATCH, m = mismatch(image.data, nearest, nearestValid, width, region);
  strength *= Math.min(Math.max((high - m) / (high - low), 0.0), 1.0);
  if (strength <= 0) return image;
  const out = inPlace ? image : tensor(new Uint8Array(image.data), [...image.shape]);
  const data = out.data, source = image.data, [x0, y0, x1, y1] = region.box, w = x1 - x0;
  const weight = region.weight.data, s = f32(Math.min(strength, 1.0));
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      const at = y * width + x, valid = f32(Math.min(Math.max(nearestValid[at], 0.0), 1.0));
      const wt = f32(f32(s * weight[(y - y0) * w + (x - x0)]) * valid), rest = f32(1.0 - wt);
      for (let c = 0; c < 3; c++) {
        const mixed = f32(f32(wt * nearest[3 * at + c]) + f32(rest * source[3 * at + c]));
        data[3 * at + c] = Math.min(Math.max(roundHalfEven(mixed), 0), 255);
      }
    }
  }
  return out;
}

/** The synthesis with the nearest warped shot's mouth, mouth mode "nearest" (lsr.core.finish.finish_mouth):
 * as far as mouthStrength says, keepNearestMouth of the first reference.
 * image: (C, C, 3) uint8 synthesis; warped: (N, C, C, 3) uint8 the references the network got (the TPS warp's,
 * nearest first), masks: (N, C, C) their validity; indices: (N,) the shots they came from; cropLandmarks: (68, 2)
 * the target in crop pixels; shotLandmarks: (K, 68, 2) the subject's shots' -> (C, C, 3) uint8 (`image` itself when
 * the shots already show this mouth, most frames; written into `image` when inPlace). */
export function finishMouthNearest(image: Tensor, warped: Tensor, masks: Tensor, indices: Tensor | number[],
                                   cropLandmarks: Tensor, shotLandmarks: Tensor, inPlace = false): Tensor {
  const [height, width] = checkImage(image, "image");
  if (warped.shape.length !== 4 || warped.shape[1] !== height || warped.shape[2] !== width || warped.shape[3] !== 3 ||
      !(warped.data instanceof Uint8Array)) {
    throw new Error(`warped must be (N, ${height}, ${width}, 3) uint8, got [${warped.shape}]`);
  }
  const strength = mouthStrength(cropLandmarks, shotLandmarks, indices);
  if (!(strength > 0)) return image; // most frames: the shots show this mouth
  const pixels = height * width;
  return keepNearestMouth(image, warped.data.subarray(0, 3 * pixels), masks.data.subarray(0, pixels), cropLandmarks,
                          strength, inPlace);
}
