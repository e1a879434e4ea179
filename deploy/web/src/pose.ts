// The head pose of 68 points and the anchor shot of a subject: landmarks/motion/head_pose.py (build_canonical_face,
// estimate_head_pose, angles_from_rotation) and landmarks/shape/expression.py (mouth_opening, eye_opening, pick_anchor).
//
// estimate_head_pose is cv2.solvePnP (EPnP, then Levenberg-Marquardt on the reprojection error) of the project's
// canonical 3-D face under a pinhole camera (focal = image width, principal point at the centre). Here the same
// least-squares pose is found from a scaled-orthographic start (the affine camera's fit) by Levenberg-Marquardt run to
// convergence: the same minimum of the same reprojection error, so the same angles to far below a degree's
// thousandth on a face that PnP finds at all (EPnP only supplies OpenCV's starting point).

import { Tensor, checkPoints, median } from "./tensor.js";

export const NUM_POINTS = 68;
const CLOSED_MOUTH = 0.05; // landmarks.shape.expression.CLOSED_MOUTH (mouth.ts exports the same)
const INNER_LIP_PAIRS: [number, number][] = [[61, 67], [62, 66], [63, 65]];
const EYE_LID_PAIRS: [number, number][] = [[37, 41], [38, 40], [43, 47], [44, 46]];

/** The canonical 3-D 68-point face (landmarks.motion.head_pose.build_canonical_face): (68, 3) flat, model units, centred. */
export function canonicalFace(): Float64Array {
  const p = new Float64Array(NUM_POINTS * 3);
  const set = (i: number, x: number, y: number) => { p[3 * i] = x; p[3 * i + 1] = y; };
  for (let k = 0; k < 17; k++) {
    const t = (Math.PI * k) / 16; // np.linspace(0, pi, 17)
    set(k, -72.0 * Math.cos(t), 118.0 * Math.sin(t));
  }
  const u = [0, 0.25, 0.5, 0.75, 1];
  const arch = u.map((v) => -16.0 - 8.0 * Math.sin(Math.PI * v));
  for (let k = 0; k < 5; k++) {
    set(17 + k, -60.0 + 48.0 * u[k], arch[k]);
    set(22 + k, 12.0 + 48.0 * u[k], arch[4 - k]);
  }
  [-2.0, 11.0, 24.0, 37.0].forEach((y, k) => set(27 + k, 0, y));
  const baseX = [-16, -8, 0, 8, 16], baseY = [43, 46, 48, 46, 43];
  for (let k = 0; k < 5; k++) set(31 + k, baseX[k], baseY[k]);
  for (const [first, centre] of [[36, -32.0], [42, 32.0]]) {
    const left = centre - 15.0, right = centre + 15.0, third = (right - left) / 3.0;
    const xs = [left, left + third, left + 2 * third, right, left + 2 * third, left + third];
    const ys = [0.0, -5.0, -5.0, 0.0, 5.0, 5.0];
    for (let k = 0; k < 6; k++) set(first + k, xs[k], ys[k]);
  }
  const outerX = [-26, -17, -7, 0, 7, 17, 26, 17, 7, 0, -7, -17], outerY = [72, 66, 63, 64, 63, 66, 72, 80, 83, 84, 83, 80];
  for (let k = 0; k < 12; k++) set(48 + k, outerX[k], outerY[k]);
  const innerX = [-22, -8, 0, 8, 22, 8, 0, -8], innerY = [72, 70, 70, 70, 72, 74, 74, 74];
  for (let k = 0; k < 8; k++) set(60 + k, innerX[k], innerY[k]);
  for (let i = 0; i < NUM_POINTS; i++) {
    const x = p[3 * i], y = p[3 * i + 1];
    const radial = 1.0 - (x / 80.0) ** 2 - ((y - 20.0) / 130.0) ** 2;
    p[3 * i + 2] = -90.0 * Math.sqrt(Math.max(radial, 0));
  }
  [-4.0, -10.0, -16.0, -25.0].forEach((dz, k) => { p[3 * (27 + k) + 2] += dz; });
  [-6.0, -12.0, -12.0, -12.0, -6.0].forEach((dz, k) => { p[3 * (31 + k) + 2] += dz; });
  for (let i = 36; i < 48; i++) p[3 * i + 2] += 8.0;
  for (let i = 17; i < 27; i++) p[3 * i + 2] += -3.0;
  for (let i = 48; i < 68; i++) p[3 * i + 2] += -5.0;
  for (let c = 0; c < 3; c++) {
    let mean = 0;
    for (let i = 0; i < NUM_POINTS; i++) mean += p[3 * i + c];
    mean /= NUM_POINTS;
    for (let i = 0; i < NUM_POINTS; i++) p[3 * i + c] -= mean;
  }
  return p;
}

const CANONICAL = canonicalFace();

type Matrix3 = Float64Array; // 3 x 3 row-major

// The Levenberg-Marquardt loop below writes into buffers it keeps (`into`, `out`): it runs every frame (the eye
// bank's head turn), and its small arrays, a thousand a frame, were garbage for the collector to sweep.

/** exp([w]) (Rodrigues), into `out`. */
function rotationFromVector(w0: number, w1: number, w2: number, out: Matrix3): Matrix3 {
  const theta = Math.hypot(w0, w1, w2);
  if (theta < 1e-300) {
    out.set(IDENTITY);
    return out;
  }
  const x = w0 / theta, y = w1 / theta, z = w2 / theta, c = Math.cos(theta), s = Math.sin(theta), v = 1 - c;
  out[0] = c + x * x * v; out[1] = x * y * v - z * s; out[2] = x * z * v + y * s;
  out[3] = y * x * v + z * s; out[4] = c + y * y * v; out[5] = y * z * v - x * s;
  out[6] = z * x * v - y * s; out[7] = z * y * v + x * s; out[8] = c + z * z * v;
  return out;
}

const IDENTITY = Float64Array.of(1, 0, 0, 0, 1, 0, 0, 0, 1);

/** a b, into `out` (not a or b). */
function multiply3(a: Matrix3, b: Matrix3, out: Matrix3): Matrix3 {
  for (let i = 0; i < 3; i++) for (let j = 0; j < 3; j++) {
    out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
  }
  return out;
}

/** Solve the symmetric positive definite n x n system a x = b (Cholesky); null when it is not. */
function solveSpd(a: Float64Array, b: Float64Array, n: number): Float64Array | null {
  const l = new Float64Array(n * n);
  for (let i = 0; i < n; i++) {
    for (let j = 0; j <= i; j++) {
      let sum = a[n * i + j];
      for (let k = 0; k < j; k++) sum -= l[n * i + k] * l[n * j + k];
      if (i === j) {
        if (!(sum > 0)) return null;
        l[n * i + i] = Math.sqrt(sum);
      } else l[n * i + j] = sum / l[n * j + j];
    }
  }
  const y = new Float64Array(n), x = new Float64Array(n);
  for (let i = 0; i < n; i++) {
    let sum = b[i];
    for (let k = 0; k < i; k++) sum -= l[n * i + k] * y[k];
    y[i] = sum / l[n * i + i];
  }
  for (let i = n - 1; i >= 0; i--) {
    let sum = y[i];
    for (let k = i + 1; k < n; k++) sum -= l[n * k + i] * x[k];
    x[i] = sum / l[n * i + i];
  }
  return x;
}

interface Pose { rotation: Matrix3; translation: [number, number, number] }

/** Reprojection residuals (2N) of model points under a pose, into `out`; null when a point is at or behind the
 * camera. */
function residuals(pose: Pose, model: Float64Array, image: Float64Array, focal: number, cx: number, cy: number,
                   out: Float64Array): Float64Array | null {
  const n = image.length / 2, r = pose.rotation, [tx, ty, tz] = pose.translation;
  for (let i = 0; i < n; i++) {
    const X = model[3 * i], Y = model[3 * i + 1], Z = model[3 * i + 2];
    const x = r[0] * X + r[1] * Y + r[2] * Z + tx, y = r[3] * X + r[4] * Y + r[5] * Z + ty;
    const z = r[6] * X + r[7] * Y + r[8] * Z + tz;
    if (!(z > 1e-9)) return null;
    out[2 * i] = (focal * x) / z + cx - image[2 * i];
    out[2 * i + 1] = (focal * y) / z + cy - image[2 * i + 1];
  }
  return out;
}

function squaredNorm(values: Float64Array): number {
  let sum = 0;
  for (const v of values) sum += v * v;
  return sum;
}

/** The pose of a small update, into `into` (not `pose`): rotation exp([w]) R, translation t + dt. */
function updated(pose: Pose, step: ArrayLike<number>, into: Pose, scratch: Matrix3): Pose {
  multiply3(rotationFromVector(step[0], step[1], step[2], scratch), pose.rotation, into.rotation);
  into.translation[0] = pose.translation[0] + step[3];
  into.translation[1] = pose.translation[1] + step[4];
  into.translation[2] = pose.translation[2] + step[5];
  return into;
}

function emptyPose(): Pose {
  return { rotation: new Float64Array(9), translation: [0, 0, 0] };
}

/** The scaled-orthographic pose that best fits the points (an affine camera, then its rotation made proper). */
function affineStart(model: Float64Array, image: Float64Array, focal: number, cx: number, cy: number): Pose {
  const n = image.length / 2;
  const mean = [0, 0, 0], centre = [0, 0];
  for (let i = 0; i < n; i++) {
    for (let c = 0; c < 3; c++) mean[c] += model[3 * i + c] / n;
    centre[0] += image[2 * i] / n; centre[1] += image[2 * i + 1] / n;
  }
  const normal = new Float64Array(9), right = [new Float64Array(3), new Float64Array(3)];
  for (let i = 0; i < n; i++) {
    const d = [model[3 * i] - mean[0], model[3 * i + 1] - mean[1], model[3 * i + 2] - mean[2]];
    const u = [image[2 * i] - centre[0], image[2 * i + 1] - centre[1]];
    for (let a = 0; a < 3; a++) {
      for (let b = 0; b < 3; b++) normal[3 * a + b] += d[a] * d[b];
      right[0][a] += d[a] * u[0]; right[1][a] += d[a] * u[1];
    }
  }
  const rows = right.map((b) => solveSpd(normal, b, 3) ?? Float64Array.of(1, 0, 0));
  const n0 = Math.hypot(...rows[0]), n1 = Math.hypot(...rows[1]);
  const scale = (n0 + n1) / 2 || 1;
  const r1 = rows[0].map((v) => v / (n0 || 1));
  const dot = r1[0] * rows[1][0] + r1[1] * rows[1][1] + r1[2] * rows[1][2];
  let r2 = rows[1].map((v, k) => v - dot * r1[k]);
  const n2 = Math.hypot(...r2) || 1;
  r2 = r2.map((v) => v / n2);
  const r3 = [r1[1] * r2[2] - r1[2] * r2[1], r1[2] * r2[0] - r1[0] * r2[2], r1[0] * r2[1] - r1[1] * r2[0]];
  const rotation = Float64Array.of(...r1, ...r2, ...r3);
  const tz = focal / scale;
  // the model's centroid projects onto the points' centroid
  const offset = [0, 1, 2].map((k) => rotation[3 * k] * mean[0] + rotation[3 * k + 1] * mean[1] + rotation[3 * k + 2] * mean[2]);
  return { rotation, translation: [((centre[0] - cx) * tz) / focal - offset[0], ((centre[1] - cy) * tz) / focal - offset[1],
                                   tz - offset[2]] };
}

/** The pose (rotation, translation) minimising the reprojection error of model points (N, 3) onto image points
 * (N, 2) under a pinhole camera (cv2.solvePnP's least squares): Levenberg-Marquardt from a scaled-orthographic
 * start. null when it finds none in front of the camera. */
export function solvePnP(model: Float64Array, image: Float64Array, focal: number, cx: number, cy: number): Pose | null {
  let pose = affineStart(model, image, focal, cx, cy), candidate = emptyPose();
  const m = image.length, probe = emptyPose(), scratch = new Float64Array(9), delta = new Float64Array(6);
  const plus = new Float64Array(m), minus = new Float64Array(m);
  let current = new Float64Array(m), next = new Float64Array(m);
  if (residuals(pose, model, image, focal, cx, cy, current) === null) return null;
  let cost = squaredNorm(current), lambda = 1e-3;
  const jacobian = new Float64Array(m * 6), jtj = new Float64Array(36), jtr = new Float64Array(6);
  const damped = new Float64Array(36);
  for (let iteration = 0; iteration < 200; iteration++) {
    for (let p = 0; p < 6; p++) { // central differences of the update parameters
      const h = p < 3 ? 1e-6 : 1e-6 * Math.max(1, Math.abs(pose.translation[2]));
      delta.fill(0);
      delta[p] = h;
      const a = residuals(updated(pose, delta, probe, scratch), model, image, focal, cx, cy, plus);
      delta[p] = -h;
      const b = a && residuals(updated(pose, delta, probe, scratch), model, image, focal, cx, cy, minus);
      if (a === null || b === null) return null;
      for (let k = 0; k < m; k++) jacobian[6 * k + p] = (a[k] - b[k]) / (2 * h);
    }
    jtj.fill(0);
    jtr.fill(0);
    for (let k = 0; k < m; k++) {
      for (let a = 0; a < 6; a++) {
        jtr[a] -= jacobian[6 * k + a] * current[k];
        for (let b = 0; b < 6; b++) jtj[6 * a + b] += jacobian[6 * k + a] * jacobian[6 * k + b];
      }
    }
    let improved = false, small = false;
    for (let attempt = 0; attempt < 30 && !improved; attempt++) {
      damped.set(jtj);
      for (let a = 0; a < 6; a++) damped[7 * a] += lambda * jtj[7 * a];
      const step = solveSpd(damped, jtr, 6);
      if (step === null) { lambda *= 10; continue; }
      updated(pose, step, candidate, scratch);
      const tried = residuals(candidate, model, image, focal, cx, cy, next);
      const nextCost = tried === null ? Infinity : squaredNorm(next);
      if (tried !== null && nextCost <= cost) {
        small = Math.hypot(step[0], step[1], step[2]) < 1e-13
          && Math.hypot(step[3], step[4], step[5]) < 1e-13 * Math.max(1, Math.abs(pose.translation[2]));
        [pose, candidate] = [candidate, pose];  // the buffers swap: the accepted pose and residuals are kept
        [current, next] = [next, current];
        const gain = cost - nextCost;
        cost = nextCost;
        lambda = Math.max(lambda / 10, 1e-12);
        improved = true;
        if (gain <= 1e-15 * Math.max(cost, 1e-300)) small = true;
      } else lambda *= 10;
    }
    if (!improved || small) break;
  }
  return pose;
}

/** (yaw, pitch, roll) degrees of a model -> camera rotation (landmarks.motion.head_pose.angles_from_rotation). */
export function anglesFromRotation(r: ArrayLike<number>): [number, number, number] {
  const b = Math.asin(Math.min(Math.max(r[7], -1), 1));
  const a = Math.atan2(-r[6], r[8]);
  const c = Math.atan2(-r[1], r[4]);
  const degrees = 180 / Math.PI;
  return [-a * degrees, -b * degrees, c * degrees];
}

/** Yaw, pitch, roll in degrees of one face (landmarks.motion.head_pose.estimate_head_pose): landmarks (68, 2) pixels of an image
 * of (height, width); NaN when they are not finite or no pose is found. */
export function estimateHeadPose(landmarks: Tensor, height: number, width: number): [number, number, number] {
  if (landmarks.shape[0] !== NUM_POINTS || landmarks.shape[1] !== 2) checkPoints(landmarks, NUM_POINTS, "landmarks");
  for (const value of landmarks.data) if (!Number.isFinite(value)) return [NaN, NaN, NaN];
  const pose = solvePnP(CANONICAL, Float64Array.from(landmarks.data), width, width / 2, height / 2);
  return pose === null ? [NaN, NaN, NaN] : anglesFromRotation(pose.rotation);
}

function gap(p: ArrayLike<number>, offset: number, pairs: [number, number][]): number {
  let sum = 0;
  for (const [a, b] of pairs) {
    sum += Math.hypot(p[offset + 2 * a] - p[offset + 2 * b], p[offset + 2 * a + 1] - p[offset + 2 * b + 1]);
  }
  return sum / pairs.length;
}

function interOcular(p: ArrayLike<number>, offset: number): number {
  let lx = 0, ly = 0, rx = 0, ry = 0;
  for (let i = 36; i < 42; i++) { lx += p[offset + 2 * i]; ly += p[offset + 2 * i + 1]; }
  for (let i = 42; i < 48; i++) { rx += p[offset + 2 * i]; ry += p[offset + 2 * i + 1]; }
  return Math.hypot(rx / 6 - lx / 6, ry / 6 - ly / 6);
}

/** Mouth opening (inner-lip gap / inter-ocular distance) of face `index` of (K, 68, 2) points
 * (landmarks.shape.expression.mouth_opening). */
export function mouthOpeningAt(points: ArrayLike<number>, index = 0): number {
  const offset = index * NUM_POINTS * 2;
  return gap(points, offset, INNER_LIP_PAIRS) / interOcular(points, offset);
}

/** Eye opening (mean lid gap / inter-ocular distance) of face `index` (landmarks.shape.expression.eye_opening). */
export function eyeOpeningAt(points: ArrayLike<number>, index = 0): number {
  const offset = index * NUM_POINTS * 2;
  return gap(points, offset, EYE_LID_PAIRS) / interOcular(points, offset);
}


/** The most frontal shot with a closed mouth and open eyes (landmarks.shape.expression.pick_anchor): landmarks (K, 68, 2)
 * in images of (height, width) -> its index. Score, lower is better: hypot(yaw, pitch) / 10 degrees, plus the mouth
 * opening above CLOSED_MOUTH in units of it, plus the eyes closed more than 0.7 of the shots' median. */
export function pickAnchor(landmarks: Tensor, height: number, width: number): number {
  const count = landmarks.shape[0], size = NUM_POINTS * 2, data = landmarks.data;
  const valid = Array.from({ length: count }, (_, k) => {
    for (let i = k * size; i < (k + 1) * size; i++) if (!Number.isFinite(data[i])) return false;
    return true;
  });
  if (!valid.some(Boolean)) return 0;
  const eyes = Array.from({ length: count }, (_, k) => eyeOpeningAt(data, k));
  const typicalEye = median(eyes.filter((_, k) => valid[k]));
  let best = 0, bestScore = Infinity;
  for (let k = 0; k < count; k++) {
    if (!valid[k]) continue;
    const face = { data: Float64Array.from(data.subarray(k * size, (k + 1) * size)), shape: [NUM_POINTS, 2] };
    const [yaw, pitch] = estimateHeadPose(face, height, width).map(Math.fround);
    const rotation = Number.isFinite(yaw) ? Math.hypot(yaw, pitch) / 10.0 : 10.0;
    const mouth = Math.max(0.0, mouthOpeningAt(data, k) - CLOSED_MOUTH) / CLOSED_MOUTH;
    const eye = Math.max(0.0, 0.7 * typicalEye - eyes[k]) / Math.max(0.1 * typicalEye, 1e-6);
    const score = rotation + mouth + eye;
    if (score < bestScore) { best = k; bestScore = score; } // np.argmin: the first of equal scores
  }
  return best;
}

/** (K, 68, 2) -> (K, 3) yaw, pitch, roll: the bridge's view of estimateHeadPose for the tests. */
export function estimateHeadPoses(landmarks: Tensor, height: number, width: number): Tensor<Float64Array> {
  const count = landmarks.shape[0], size = NUM_POINTS * 2, out = new Float64Array(count * 3);
  for (let k = 0; k < count; k++) {
    const face = { data: Float64Array.from(landmarks.data.subarray(k * size, (k + 1) * size)), shape: [NUM_POINTS, 2] };
    out.set(estimateHeadPose(face, height, width), 3 * k);
  }
  return { data: out, shape: [count, 3] };
}
