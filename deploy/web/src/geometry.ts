// Crop framing and 2-D transforms: landmarks/align.py (crop_transform, transform_landmarks, invert_affine) and
// landmarks/motion/retarget_points.py (similarity_procrustes, apply_similarity). Same constants, same conventions.

import { Affine, Tensor, checkPoints, tensor } from "./tensor.js";

// landmarks/align.py: the VoxCeleb2 framing, calibrated on the FSTH sample's frames
export const IOD_FRACTION = 0.2184;
export const EYE_MOUTH_FRACTION = 0.2645;
export const SIZE_NORMALISER = 1.031;
export const ANCHOR_FRACTION: [number, number] = [0.504, 0.393];
export const LEFT_EYE = [36, 37, 38, 39, 40, 41];
export const RIGHT_EYE = [42, 43, 44, 45, 46, 47];
export const MOUTH_CORNERS = [48, 54];

function mean(points: Tensor, indices: number[]): [number, number] {
  let x = 0, y = 0;
  for (const i of indices) { x += points.data[2 * i]; y += points.data[2 * i + 1]; }
  return [x / indices.length, y / indices.length];
}

/** (eye centre left, eye centre right, mouth centre) of (68, 2) landmarks (landmarks.align.face_geometry). */
export function faceGeometry(landmarks: Tensor): [[number, number], [number, number], [number, number]] {
  checkPoints(landmarks, 68, "landmarks");
  return [mean(landmarks, LEFT_EYE), mean(landmarks, RIGHT_EYE), mean(landmarks, MOUTH_CORNERS)];
}

/** The similarity frame -> crop that frames a face like the training crops (landmarks.align.crop_transform, the
 * frame's vertical kept). */
export function cropTransform(landmarks: Tensor, cropSize: number, scale = 1.0): Affine {
  const [left, right, mouth] = faceGeometry(landmarks);
  const eyes = [(left[0] + right[0]) / 2, (left[1] + right[1]) / 2];
  const interOcular = Math.hypot(right[0] - left[0], right[1] - left[1]);
  const eyeMouth = Math.hypot(mouth[0] - eyes[0], mouth[1] - eyes[1]);
  const side = (Math.max(interOcular / IOD_FRACTION, eyeMouth / EYE_MOUTH_FRACTION) / SIZE_NORMALISER) * scale;
  if (!(side > 0)) throw new Error("degenerate landmarks: eyes and mouth coincide, cannot size the crop");
  const zoom = cropSize / side;
  const anchor = [(eyes[0] + mouth[0]) / 2, (eyes[1] + mouth[1]) / 2];
  const anchorCrop = [ANCHOR_FRACTION[0] * cropSize - 0.5, ANCHOR_FRACTION[1] * cropSize - 0.5];
  return [zoom, 0, anchorCrop[0] - zoom * anchor[0], 0, zoom, anchorCrop[1] - zoom * anchor[1]];
}

/** Points (N, 2) under an affine -> (N, 2) float64 (landmarks.align.transform_landmarks). */
export function transformPoints(points: Tensor, m: Affine): Tensor<Float64Array> {
  const out = new Float64Array(points.data.length);
  for (let i = 0; i < out.length; i += 2) {
    const x = points.data[i], y = points.data[i + 1];
    out[i] = m[0] * x + m[1] * y + m[2];
    out[i + 1] = m[3] * x + m[4] * y + m[5];
  }
  return tensor(out, [...points.shape]);
}

export function invertAffine(m: Affine): Affine {
  const det = m[0] * m[4] - m[1] * m[3];
  if (Math.abs(det) < 1e-12) throw new Error("affine transform is singular (zero scale) and cannot be inverted");
  const a = m[4] / det, b = -m[1] / det, d = -m[3] / det, e = m[0] / det;
  return [a, b, -(a * m[2] + b * m[5]), d, e, -(d * m[2] + e * m[5])];
}

/** Apply a then b: the affine of b(a(p)). */
export function composeAffine(b: Affine, a: Affine): Affine {
  return [b[0] * a[0] + b[1] * a[3], b[0] * a[1] + b[1] * a[4], b[0] * a[2] + b[1] * a[5] + b[2],
          b[3] * a[0] + b[4] * a[3], b[3] * a[1] + b[4] * a[4], b[3] * a[2] + b[4] * a[5] + b[5]];
}

/** A similarity (scale, rotation, translation) as the Python side returns it. */
export interface Similarity { scale: number; rotation: [number, number, number, number]; translation: [number, number] }

/** Least-squares similarity taking source (N, 2) onto target (N, 2), no reflection (Umeyama; in 2-D closed form)
 * (landmarks.motion.retarget_points.similarity_procrustes). indices: the rows to fit on (all when omitted). */
export function similarityProcrustes(source: Tensor, target: Tensor, indices?: number[]): Similarity {
  const rows = indices ?? Array.from({ length: source.shape[0] }, (_, i) => i);
  if (rows.length < 2) throw new Error("a similarity needs at least 2 points");
  const [sx, sy] = mean(source, rows), [tx, ty] = mean(target, rows);
  let a = 0, b = 0, variance = 0;
  for (const i of rows) {
    const px = source.data[2 * i] - sx, py = source.data[2 * i + 1] - sy;
    const qx = target.data[2 * i] - tx, qy = target.data[2 * i + 1] - ty;
    a += px * qx + py * qy;
    b += px * qy - py * qx;
    variance += px * px + py * py;
  }
  if (variance < 1e-12 * rows.length) throw new Error("source points all coincide: the similarity is undefined");
  const r = Math.hypot(a, b);
  const cos = r > 0 ? a / r : 1, sin = r > 0 ? b / r : 0;
  const scale = r / variance;
  const translation: [number, number] = [tx - scale * (cos * sx - sin * sy), ty - scale * (sin * sx + cos * sy)];
  return { scale, rotation: [cos, -sin, sin, cos], translation };
}

export function similarityAffine(s: Similarity): Affine {
  const [r00, r01, r10, r11] = s.rotation;
  return [s.scale * r00, s.scale * r01, s.translation[0], s.scale * r10, s.scale * r11, s.translation[1]];
}

/** scale * R p + t for points (N, 2) (landmarks.motion.retarget_points.apply_similarity). */
export function applySimilarity(points: Tensor, s: Similarity): Tensor<Float64Array> {
  return transformPoints(points, similarityAffine(s));
}
