// Shut eyes from the driver's own frame: landmarks/parts/eyes/driver_lids.py (aperture_share, shut_strength, cut_driver_eyes,
// similarity, ellipse_mask, paste_eyes), as the live session finishes a frame with lids "driver". The driver's frame
// around its eyes is cut where the frame is (cutEyePatch: the tracker's worker, or this thread); how shut they are is
// read here, against the driver's lids at rest (shutEyes: the session keeps that reference). Each eye is mapped onto
// the target by the similarity of the eye corners (bicubic, as cv2.warpAffine with WARP_INVERSE_MAP), lit as the
// target is (interior.ts matchLight with the whole colour cast: skin laid on skin) and laid inside a feathered
// ellipse over the target's eye. The module's REACH, REGION, FEATHER and RING are EYE_REACH, EYE_REGION,
// EYE_FEATHER and EYE_RING here (interior.ts has its own).

import { TURN, checkLandmarks, cutAround, matchLight } from "./interior.js";
import { estimateHeadPose } from "./pose.js";
import { gaussianBlurF32, roundHalfEven, warpAffineCubic } from "./remap.js";
import { closedGap, finite, flat, interOcularDistance, lidGaps } from "./retarget.js";
import { Affine, Tensor, tensor } from "./tensor.js";

export const SHUT: [number, number] = [0.25, 0.5];
export const EYE_REACH = 0.35;
export const EYE_REGION: [number, number] = [0.7, 0.45];
export const EYE_FEATHER = 0.12;
export const EYE_RING = 0.08;
/** Each eye's outer and inner corner of the 68 points. */
const CORNERS: [number, number][] = [[36, 39], [42, 45]];

const f32 = Math.fround;

/** The driver frame around its eyes, cut on the tracking side, before anything says how shut they are. */
export interface EyePatch {
  /** (h, w, 3) uint8 RGB: the driver frame around its eyes. */
  patch: Tensor<Uint8Array>;
  /** (2, 2, 2) float64: each eye's outer and inner corner in the patch's pixels. */
  corners: Tensor<Float64Array>;
  /** The driver frame's (height, width), for its head pose where the eyes shut. */
  frameSize: [number, number];
}

/** A driver frame's shut eyes (landmarks.parts.eyes.driver_lids.DriverEyes): the patch and how much of it to lay in. */
export interface DriverEyes extends EyePatch {
  /** In (0, 1]. */
  strength: number;
}

/** aperture_share: the mean over both eyes of (lid gap - closed gap) / (reference gap - closed gap) of (68, 2) points
 * against the driver's lids at rest (2,) (NaN when either is not finite or a reference is no wider than closed). */
export function apertureShare(landmarks: Tensor | ArrayLike<number>,
                              referenceGaps: Tensor | ArrayLike<number>): number {
  const gaps = lidGaps(landmarks), reference = flat(referenceGaps);
  let sum = 0;
  for (let e = 0; e < 2; e++) {
    const shut = closedGap(reference[e]);
    sum += reference[e] > shut ? (gaps[e] - shut) / (reference[e] - shut) : NaN;
  }
  return sum / 2;
}

/** shut_strength: none from an aperture share of SHUT[1], wholly from SHUT[0] down, less as the head turns from TURN[0]
 * to TURN[1] degrees of `yaw` (none where the share or the yaw is not finite). */
export function shutStrength(landmarks: Tensor | ArrayLike<number>, referenceGaps: Tensor | ArrayLike<number>,
                             yaw: number): number {
  const share = apertureShare(landmarks, referenceGaps);
  if (!Number.isFinite(share) || !Number.isFinite(yaw)) return 0;
  const shut = Math.min(Math.max((SHUT[1] - share) / (SHUT[1] - SHUT[0]), 0), 1);
  return shut * Math.min(Math.max((TURN[1] - Math.abs(yaw)) / (TURN[1] - TURN[0]), 0), 1);
}

/** The driver frame (H, W, 3) uint8 around the eyes of its 68 points (frame pixels), or null when the points are not
 * finite or the box lies outside the frame: cut_driver_eyes' patch, before its strength. */
export function cutEyePatch(frame: Tensor<Uint8Array>, landmarks: Tensor): EyePatch | null {
  if (frame.shape.length !== 3 || frame.shape[2] !== 3) throw new Error(`frame must be (H, W, 3), got [${frame.shape}]`);
  const p = checkLandmarks(landmarks);
  if (!finite(p)) return null;
  const cut = cutAround(frame, p, 36, 48, EYE_REACH * interOcularDistance(p));
  if (cut === null) return null;
  const { x0, y0 } = cut, corners = new Float64Array(8);
  CORNERS.forEach(([outer, inner], e) => {
    corners.set([p[2 * outer] - x0, p[2 * outer + 1] - y0, p[2 * inner] - x0, p[2 * inner + 1] - y0], 4 * e);
  });
  return { patch: cut.patch, corners: tensor(corners, [2, 2, 2]), frameSize: [frame.shape[0], frame.shape[1]] };
}

/** The cut patch with how shut its eyes are against the driver's lids at rest (2,) (DriverReference.lids), or null
 * where they are not shut (strength 0, most frames). */
export function shutEyes(cut: EyePatch | null, landmarks: Tensor, referenceGaps: Tensor | ArrayLike<number>
                         ): DriverEyes | null {
  if (cut === null || !finite(checkLandmarks(landmarks))) return null;
  if (!(apertureShare(landmarks, referenceGaps) < SHUT[1])) return null;  // open (most frames): no head pose
  const strength = shutStrength(landmarks, referenceGaps, estimateHeadPose(landmarks, ...cut.frameSize)[0]);
  return strength > 0 ? { ...cut, strength } : null;
}

/** cut_driver_eyes: cutEyePatch, then shutEyes. */
export function cutDriverEyes(frame: Tensor<Uint8Array>, landmarks: Tensor, referenceGaps: Tensor | ArrayLike<number>
                              ): DriverEyes | null {
  return shutEyes(cutEyePatch(frame, landmarks), landmarks, referenceGaps);
}

/** similarity: the map [a, b, c, d, e, f] (x' = a x + b y + c, y' = d x + e y + f) of rotation, uniform scale and
 * shift that takes the two points `from` (x0, y0, x1, y1) onto `to` exactly. */
export function similarity(source: Tensor | ArrayLike<number>, target: Tensor | ArrayLike<number>): Affine {
  const from = flat(source), to = flat(target);
  const sx = from[2] - from[0], sy = from[3] - from[1], tx = to[2] - to[0], ty = to[3] - to[1];
  const norm = sx * sx + sy * sy, re = (tx * sx + ty * sy) / norm, im = (ty * sx - tx * sy) / norm;
  return [re, -im, to[0] - (re * from[0] - im * from[1]), im, re, to[1] - (im * from[0] + re * from[1])];
}

/** ellipse_mask: 1 where a pixel's centre lies inside the ellipse of semi-axes `axes` along the unit direction
 * (ux, uy) and across it, around (cx, cy); (h, w) float32. */
export function ellipseMask(cx: number, cy: number, axes: [number, number], ux: number, uy: number, w: number,
                            h: number): Float32Array {
  const mask = new Float32Array(w * h);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const dx = x - cx, dy = y - cy, u = dx * ux + dy * uy, v = dy * ux - dx * uy;
      mask[y * w + x] = (u / axes[0]) ** 2 + (v / axes[1]) ** 2 <= 1.0 ? 1 : 0;
    }
  }
  return mask;
}

/** paste_eyes: `image` (S, S, 3) uint8, the synthesis for the target's (68, 2) points, with the driver's shut eyes laid
 * over its own; `image` itself when there is nothing to lay in, else a new image (or `image` written in place when
 * inPlace). */
export function pasteEyes(image: Tensor, landmarks: Tensor, eyes: DriverEyes | null, inPlace = false): Tensor {
  if (image.shape.length !== 3 || image.shape[2] !== 3 || !(image.data instanceof Uint8Array)) {
    throw new Error(`image must be (H, W, 3) uint8, got [${image.shape}]`);
  }
  const p = checkLandmarks(landmarks);
  if (eyes === null || !finite(p) || !(eyes.strength > 0)) return image;
  const ring = Math.max(1, roundHalfEven(EYE_RING * interOcularDistance(p)));
  const [height, width] = image.shape, [ph, pw] = eyes.patch.shape;
  const out = inPlace ? image : tensor(new Uint8Array(image.data as Uint8Array), [...image.shape]);
  const data = out.data as Uint8Array, s = f32(eyes.strength);
  CORNERS.forEach(([outer, inner], e) => {
    const ax = p[2 * outer], ay = p[2 * outer + 1], bx = p[2 * inner], by = p[2 * inner + 1];
    const eyeWidth = Math.hypot(bx - ax, by - ay);
    if (eyeWidth < 1.0) return;
    const axes: [number, number] = [EYE_REGION[0] * eyeWidth, EYE_REGION[1] * eyeWidth];
    const sigma = Math.max(0.5, EYE_FEATHER * eyeWidth), margin = axes[0] + ring + 3 * sigma + 1;
    const cx = (ax + bx) / 2, cy = (ay + by) / 2;
    const x0 = Math.max(Math.floor(cx - margin), 0), y0 = Math.max(Math.floor(cy - margin), 0);
    const x1 = Math.min(Math.ceil(cx + margin) + 1, width), y1 = Math.min(Math.ceil(cy + margin) + 1, height);
    if (x1 - x0 < 2 || y1 - y0 < 2) return;
    const w = x1 - x0, h = y1 - y0;
    const warped = warpAffineCubic({ data: eyes.patch.data, width: pw, height: ph, channels: 3 },
                                   similarity([ax - x0, ay - y0, bx - x0, by - y0],
                                              eyes.corners.data.subarray(4 * e, 4 * e + 4)),
                                   w, h, "replicate");
    const region = new Float32Array(w * h * 3), mapped = Float32Array.from(warped);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w * 3; x++) region[3 * y * w + x] = data[3 * ((y0 + y) * width + x0) + x];
    }
    const inside = ellipseMask(cx - x0, cy - y0, axes, (bx - ax) / eyeWidth, (by - ay) / eyeWidth, w, h);
    const laid = matchLight(mapped, region, Uint8Array.from(inside), w, h, ring, 1.0, null);  // skin on skin
    const weight = gaussianBlurF32(inside, w, h, 1, sigma);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        const k = y * w + x, wt = f32(weight[k] * s), rest = f32(1.0 - wt), at = 3 * ((y0 + y) * width + x0 + x);
        for (let c = 0; c < 3; c++) {
          const mixed = f32(f32(wt * laid[3 * k + c]) + f32(rest * region[3 * k + c]));
          data[at + c] = Math.min(Math.max(roundHalfEven(mixed), 0), 255);
        }
      }
    }
  });
  return out;
}
