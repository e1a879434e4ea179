// The live path between the tracker and the network: the driver's motion moved onto the subject's anchor face.
// Ports of landmarks/motion/retarget_points.py (retarget_relative, retarget_driving), landmarks/shape/expression.py (mouth_opening,
// signed_mouth_gap, set_mouth_opening), landmarks/parts/eyes/lids.py (lid_gaps, set_lid_gaps, closed_gaps, lid_share,
// lids_as_driver, LidReference), landmarks/motion/retarget_mesh.py (DriverReference, 68 points only: the web path has no
// mesh) and the per-frame steps of lsr/core/live_session.py (LiveSession.prepare). Same constants, same order of operations.
// Points are (68, 2) float64 in row-major (x, y).

import { Similarity, cropTransform, similarityProcrustes, transformPoints } from "./geometry.js";
import { Tensor, checkPoints, columnMedian, tensor } from "./tensor.js";

/** Points barely moved by expressions: upper jaw, nose, eye corners and lids (landmarks.motion.retarget_points.RIGID_INDEX). */
export const RIGID_INDEX: number[] = [0, 1, 2, 14, 15, 16, 27, 28, 29, 30, 31, 32, 33, 34, 35,
  36, 37, 38, 39, 40, 41, 42, 43, 44, 45, 46, 47];

// landmarks/parts/eyes/lids.py
export const LID_CLOSED = 0.04;
export const CLOSED_SHARE = 0.3;
export const MAX_APERTURE = 1.5;
export const MIN_APERTURE = 0.02;
export const SMALL_LID_GAIN = 3.0;
export const SMALL_LID_SPAN = 0.35;
export const REST_FRAMES = 250;

// landmarks/shape/expression.py
const INNER_LIP_PAIRS: [number, number][] = [[61, 67], [62, 66], [63, 65]];
const JAW_DROP: [number, number][] = [[65, 1.0], [66, 1.0], [67, 1.0], [55, 1.0], [56, 1.0], [57, 1.0], [58, 1.0],
  [59, 1.0], [60, 0.5], [64, 0.5], [48, 0.4], [54, 0.4], [6, 0.9], [7, 1.0], [8, 1.0], [9, 1.0], [10, 0.9], [5, 0.7],
  [11, 0.7], [4, 0.4], [12, 0.4], [3, 0.15], [13, 0.15]];

// landmarks/eyelids.POINTS_68_LIDS: per eye (outer corner, inner corner, upper lid, lower lid); the middle upper
// points (0, 1) measure the gap
const LIDS_68: [number, number, number[], number[]][] = [[36, 39, [37, 38], [41, 40]], [42, 45, [43, 44], [47, 46]]];

/** A tensor's flat values, or the values themselves. */
export function flat(points: Tensor | ArrayLike<number>): ArrayLike<number> {
  return "shape" in points ? points.data : points;
}

/** Whether every value is finite. */
export function finite(values: ArrayLike<number>): boolean {
  for (let i = 0; i < values.length; i++) if (!Number.isFinite(values[i])) return false;
  return true;
}

function eyeCentre(p: ArrayLike<number>, first: number): [number, number] {
  let x = 0, y = 0;
  for (let i = first; i < first + 6; i++) { x += p[2 * i]; y += p[2 * i + 1]; }
  return [x / 6, y / 6];
}

/** Distance between the two eye centres (points 36-41 and 42-47) of (68, 2) points
 * (landmarks.motion.smooth.inter_ocular_distance). */
export function interOcularDistance(landmarks: Tensor | ArrayLike<number>): number {
  const points = flat(landmarks);
  const [lx, ly] = eyeCentre(points, 36), [rx, ry] = eyeCentre(points, 42);
  const dx = rx - lx, dy = ry - ly;
  return Math.sqrt(dx * dx + dy * dy);
}

/** Inner-lip gap over the inter-ocular distance (landmarks.shape.expression.mouth_opening) of (68, 2) points. */
export function mouthOpening(landmarks: Tensor | ArrayLike<number>): number {
  const points = flat(landmarks);
  let sum = 0;
  for (const [a, b] of INNER_LIP_PAIRS) {
    const dx = points[2 * a] - points[2 * b], dy = points[2 * a + 1] - points[2 * b + 1];
    sum += Math.sqrt(dx * dx + dy * dy);
  }
  return sum / 3 / interOcularDistance(points);
}

/** landmarks.shape.expression.signed_mouth_gap: the lower inner lip's mean height below the upper along `down`. */
function signedMouthGap(p: ArrayLike<number>, downX: number, downY: number): number {
  let sum = 0;
  for (const [upper, lower] of INNER_LIP_PAIRS) {
    sum += (p[2 * lower] - p[2 * upper]) * downX + (p[2 * lower + 1] - p[2 * upper + 1]) * downY;
  }
  return sum / 3 / interOcularDistance(p);
}

function nanToNum(value: number): number {
  if (Number.isNaN(value)) return 0;
  if (value === Infinity) return Number.MAX_VALUE;
  if (value === -Infinity) return -Number.MAX_VALUE;
  return value;
}

/** The face's mouth opened or closed to `opening` (a mouth_opening), the lower lip and jaw moved along the face's
 * down direction as a jaw drop does (landmarks.shape.expression.set_mouth_opening). (68, 2) -> a new (68, 2). */
export function setMouthOpening(landmarks: Tensor, opening: number): Tensor<Float64Array> {
  const p = Float64Array.from(landmarks.data);
  const distance = interOcularDistance(p);
  const target = Number.isNaN(opening) ? NaN : Math.max(opening, 0.0);
  const [lx, ly] = eyeCentre(p, 36), [rx, ry] = eyeCentre(p, 42);
  let downX = (p[96] + p[108]) / 2 - (lx + rx) / 2, downY = (p[97] + p[109]) / 2 - (ly + ry) / 2;
  const norm = Math.max(Math.sqrt(downX * downX + downY * downY), 1e-9);
  downX /= norm;
  downY /= norm;
  dropJaw(p, (target - signedMouthGap(p, downX, downY)) * distance, downX, downY);
  for (let k = 0; k < 3; k++) {
    const want = target - mouthOpening(p), floor = -signedMouthGap(p, downX, downY);
    dropJaw(p, (Number.isNaN(want) || Number.isNaN(floor) ? NaN : Math.max(want, floor)) * distance, downX, downY);
  }
  return tensor(p, [68, 2]);
}

/** The lower lip and jaw of (68, 2) flat `p` moved by `length` (NaN: not at all) along (downX, downY), each point by
 * its JAW_DROP share (setMouthOpening's step). */
function dropJaw(p: Float64Array, length: number, downX: number, downY: number): void {
  const v = nanToNum(length), mx = v * downX, my = v * downY;
  for (const [i, amount] of JAW_DROP) { p[2 * i] += amount * mx; p[2 * i + 1] += amount * my; }
}

// ---------------------------------------------------------------------------------------------------------- lids

/** The indices of `keys` in ascending order of their keys, equal keys by index (a stable insertion sort: the lists
 * here are a lid's few points; a comparator closure per call was optimised again by V8 on every frame). */
function orderBy(keys: number[]): number[] {
  const order: number[] = [];
  for (let k = 0; k < keys.length; k++) {
    let at = order.length;
    while (at > 0 && (keys[order[at - 1]] - keys[k] || order[at - 1] - k) > 0) at--;
    order.splice(at, 0, k);
  }
  return order;
}

/** numpy.interp for an increasing xp (numpy's own branches: outside -> the end values, on a knot -> its value). */
export function numpyInterp(x: number, xp: number[], fp: number[]): number {
  const n = xp.length;
  if (Number.isNaN(x)) return x;
  if (x > xp[n - 1]) return fp[n - 1];
  if (x < xp[0]) return fp[0];
  let j = 1;
  while (j < n && x >= xp[j]) j++;
  j -= 1;
  if (j === n - 1) return fp[j];
  if (xp[j] === x) return fp[j];
  const slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j]);
  let result = slope * (x - xp[j]) + fp[j];
  if (Number.isNaN(result)) {
    result = slope * (x - xp[j + 1]) + fp[j + 1];
    if (Number.isNaN(result) && fp[j] === fp[j + 1]) result = fp[j];
  }
  return result;
}

interface EyeMeasure { acrossX: number; acrossY: number; opening: number[]; gap: number }

/** landmarks.parts.eyes.lids._measure on (68, 2) points: per eye (across, lower minus upper lid heights at the upper points,
 * gap in inter-ocular distances). */
function measureLids(p: ArrayLike<number>): EyeMeasure[] {
  const [o0, i0] = LIDS_68[0], [o1, i1] = LIDS_68[1];
  const rx = p[2 * o0] + p[2 * i0], ry = p[2 * o0 + 1] + p[2 * i0 + 1];
  const lx = p[2 * o1] + p[2 * i1], ly = p[2 * o1 + 1] + p[2 * i1 + 1];
  const scale = Math.sqrt((rx - lx) * (rx - lx) + (ry - ly) * (ry - ly)) / 2;
  const measured: EyeMeasure[] = [];
  for (const [outer, inner, upper, lower] of LIDS_68) {
    const ox = (p[2 * outer] + p[2 * inner]) / 2, oy = (p[2 * outer + 1] + p[2 * inner + 1]) / 2;
    const lineX = p[2 * inner] - p[2 * outer], lineY = p[2 * inner + 1] - p[2 * outer + 1];
    const length = Math.sqrt(lineX * lineX + lineY * lineY);
    const alongX = length > 1e-9 ? lineX / length : NaN, alongY = length > 1e-9 ? lineY / length : NaN;
    const acrossX = -alongY, acrossY = alongX;
    const opening: number[] = [];
    if (!(Number.isFinite(alongX) && Number.isFinite(alongY))) {
      for (let k = 0; k < upper.length; k++) opening.push(NaN);
    } else {
      const n = lower.length, lowerAlong: number[] = new Array(n), lowerAcross: number[] = new Array(n);
      for (let k = 0; k < n; k++) {
        const i = lower[k];
        lowerAlong[k] = (p[2 * i] - ox) * alongX + (p[2 * i + 1] - oy) * alongY;
        lowerAcross[k] = (p[2 * i] - ox) * acrossX + (p[2 * i + 1] - oy) * acrossY;
      }
      const order = orderBy(lowerAlong), xp: number[] = new Array(n), fp: number[] = new Array(n);
      for (let k = 0; k < n; k++) { xp[k] = lowerAlong[order[k]]; fp[k] = lowerAcross[order[k]]; }
      for (const i of upper) {
        const ux = p[2 * i] - ox, uy = p[2 * i + 1] - oy;
        opening.push(numpyInterp(ux * alongX + uy * alongY, xp, fp) - (ux * acrossX + uy * acrossY));
      }
    }
    // the middle upper points (0, 1): the mean of |lower - upper|
    const gap = scale > 0 ? (Math.abs(opening[0]) + Math.abs(opening[1])) / 2 / scale : NaN;
    measured.push({ acrossX, acrossY, opening, gap });
  }
  return measured;
}

/** Each eye's lid gap over the inter-ocular distance (landmarks.parts.eyes.lids.lid_gaps) of (68, 2) points -> (2,) (NaN when
 * the face is not finite). */
export function lidGaps(landmarks: Tensor | ArrayLike<number>): Float64Array {
  const points = flat(landmarks);
  if (!finite(points)) return new Float64Array([NaN, NaN]);
  const [a, b] = measureLids(points);
  return new Float64Array([a.gap, b.gap]);
}

/** The face with each upper lid moved across its eye's corner line so that lidGaps reads `gaps`
 * (landmarks.parts.eyes.lids.set_lid_gaps): in place on p (68, 2) values. */
function setLidGapsInPlace(p: Float64Array, gaps: ArrayLike<number>): void {
  if (!finite(p)) return;
  const measured = measureLids(p);
  for (let e = 0; e < 2; e++) {
    const { acrossX, acrossY, opening, gap } = measured[e], goal = gaps[e];
    if (!(gap > 0 && goal >= 0 && Number.isFinite(gap * goal))) continue;
    const upper = LIDS_68[e][2];
    for (let k = 0; k < upper.length; k++) {
      const move = opening[k] * (1.0 - goal / gap);
      p[2 * upper[k]] += move * acrossX;
      p[2 * upper[k] + 1] += move * acrossY;
    }
  }
}

/** landmarks.parts.eyes.lids.set_lid_gaps on (68, 2) points -> a new (68, 2). */
export function setLidGaps(points: Tensor, gaps: Tensor | ArrayLike<number>): Tensor<Float64Array> {
  const p = Float64Array.from(points.data);
  setLidGapsInPlace(p, flat(gaps));
  return tensor(p, [68, 2]);
}

/** A closed eye's lid gap from its open gap (landmarks.parts.eyes.lids.closed_gaps). */
export function closedGap(open: number, closed = LID_CLOSED): number {
  const share = CLOSED_SHARE * open;
  return Number.isNaN(share) ? NaN : Math.min(closed, share);
}

/** The share of the source's aperture its lids take for a driver at `share` of its reference's
 * (landmarks.parts.eyes.lids.lid_share). */
export function lidShare(share: number, gain = SMALL_LID_GAIN, span = SMALL_LID_SPAN): number {
  let change = share - 1.0;
  if (span > 0) {
    const r = change / span;
    change = change + (gain - 1.0) * change * Math.exp(-(r * r));
  }
  const value = 1.0 + change;
  return Number.isNaN(value) ? NaN : Math.min(Math.max(value, 0.0), MAX_APERTURE);
}

let driverShareTable: [number[], number[]] | null = null;

/** The inverse of lidShare (landmarks.parts.eyes.lids.driver_share, the module's gain and span): the driver's share of
 * its reference's aperture that lidShare maps onto `share` (the smallest, where lidShare clips). A part shown as it
 * is, not warped (eye_bank.ts), follows the driver's own lid motion, not its small motions multiplied. */
export function driverShare(share: number): number {
  if (driverShareTable === null) {
    const count = 1201, step = (2.0 * MAX_APERTURE) / (count - 1), xp: number[] = [], fp: number[] = [];
    let running = -Infinity;
    for (let i = 0; i < count; i++) {
      const grid = i === count - 1 ? 2.0 * MAX_APERTURE : i * step;  // np.linspace
      const mapped = Math.max(running, lidShare(grid));  // np.maximum.accumulate
      if (i === 0 || mapped > running) { xp.push(mapped); fp.push(grid); }  // xp must increase: a clipped run keeps its first
      running = mapped;
    }
    driverShareTable = [xp, fp];
  }
  return numpyInterp(share, ...driverShareTable);
}

/** A retargeted face (68, 2) with its lids as closed as its driver's, in proportion
 * (landmarks.parts.eyes.lids.lids_as_driver, one frame): in place on `face`. */
function lidsAsDriverInPlace(face: Float64Array, driver: ArrayLike<number>, referenceGaps: ArrayLike<number>,
                             source: ArrayLike<number>, closed = LID_CLOSED): void {
  const sourceGaps = lidGaps(source);
  if (!finite(sourceGaps) || closed <= 0) return;
  if (!(finite(face) && finite(driver) && finite(referenceGaps))) return;
  const driverGaps = lidGaps(driver), goal = new Float64Array(2);
  for (let e = 0; e < 2; e++) {
    const sourceShut = closedGap(sourceGaps[e], closed), driverShut = closedGap(referenceGaps[e], closed);
    const share = (driverGaps[e] - driverShut) / Math.max(referenceGaps[e] - driverShut, MIN_APERTURE);
    goal[e] = sourceShut + (sourceGaps[e] - sourceShut) * lidShare(share);
  }
  setLidGapsInPlace(face, goal);
}


/** The driver's reference lid gaps, robust to a blink: the median lidGaps of its last `frames` faces (and those seen
 * ahead) (landmarks.parts.eyes.lids.LidReference). Call on each driver face in order -> (2,), NaN before the first. */
export class LidReference {
  private readonly gaps: Float64Array[] = [];
  private ahead = 0;

  constructor(readonly frames = REST_FRAMES) {}

  reset(): void {
    this.gaps.length = 0;
    this.ahead = 0;
  }

  private add(driver: ArrayLike<number>): void {
    const gaps = lidGaps(driver);
    if (!finite(gaps)) return;
    this.gaps.push(gaps);
    if (this.gaps.length > this.frames) this.gaps.shift();
  }

  /** The driver's next faces (null: no face), counted before the first is driven. */
  lookAhead(drivers: (ArrayLike<number> | null)[]): void {
    for (const driver of drivers) {
      this.ahead += 1;
      if (driver !== null) this.add(driver);
    }
  }

  call(driver: ArrayLike<number>): Float64Array {
    if (this.ahead) this.ahead -= 1;
    else this.add(driver);
    if (!this.gaps.length) return new Float64Array([NaN, NaN]);
    return new Float64Array([columnMedian(this.gaps, 0), columnMedian(this.gaps, 1)]);
  }
}

/** A stream's driver reference (landmarks.motion.retarget_mesh.DriverReference, 68 points only): the first face in crop
 * pixels, which relative motion is measured from, and the reference lid gaps. `lids` on each driver face as
 * detected, then `start` on the first one; `reset` for a new driver (LiveSession.recentre). */
export class DriverReference {
  landmarks: Tensor<Float64Array> | null = null;
  readonly lidReference = new LidReference();

  /** The reference face, unless there is one already. */
  start(landmarks: Tensor): void {
    if (this.landmarks === null) this.landmarks = tensor(Float64Array.from(landmarks.data), [68, 2]);
  }

  reset(): void {
    this.landmarks = null;
    this.lidReference.reset();
  }

  /** One driver face (68, 2) as detected -> the reference lid gaps of its 68 points (2,) (NaN: none yet). Python's
   * also returns the mesh's; the web path has none. */
  lids(landmarks: Tensor): Float64Array {
    return this.lidReference.call(landmarks.data);
  }
}

// ----------------------------------------------------------------------------------------------------- retarget

function applySim(points: ArrayLike<number>, s: Similarity): Float64Array {
  const [r00, r01, r10, r11] = s.rotation, a = s.scale * r00, b = s.scale * r01, d = s.scale * r10, e = s.scale * r11;
  const [tx, ty] = s.translation, out = new Float64Array(points.length);
  for (let i = 0; i < out.length; i += 2) {
    const x = points[i], y = points[i + 1];
    out[i] = x * a + y * b + tx;
    out[i + 1] = x * d + y * e + ty;
  }
  return out;
}

/** (scale, R, t) -> (1 / scale, R^T, -R^T t / scale) (landmarks.motion.retarget_points.invert_similarity). */
export function invertSimilarity(s: Similarity): Similarity {
  const [r00, r01, r10, r11] = s.rotation, [tx, ty] = s.translation;
  return { scale: 1.0 / s.scale, rotation: [r00, r10, r01, r11],
           translation: [-(r00 * tx + r10 * ty) / s.scale, -(r01 * tx + r11 * ty) / s.scale] };
}

/** The driver's motion relative to its reference frame moved onto the source's face, one frame
 * (landmarks.motion.retarget_points.retarget_relative): driver, driverReference, source (68, 2) -> (68, 2) (NaN when the driver
 * frame is not finite). */
export function retargetRelative(driver: Tensor, driverReference: Tensor, source: Tensor): Tensor<Float64Array> {
  checkPoints(driverReference, 68, "driver_reference");
  checkPoints(source, 68, "source");
  if (driver.shape.length !== 2 || driver.shape[0] !== 68 || driver.shape[1] !== 2) {
    throw new Error(`driver must be (68, 2), got [${driver.shape}]`);
  }
  if (!finite(driver.data)) return tensor(new Float64Array(136).fill(NaN), [68, 2]);
  const place = similarityProcrustes(driverReference, source, RIGID_INDEX);
  const unplace = invertSimilarity(place);
  const [p00, p01, p10, p11] = place.rotation.map((r) => place.scale * r);
  const motion = similarityProcrustes(driverReference, driver, RIGID_INDEX); // step 1
  const unmoved = applySim(driver.data, invertSimilarity(motion)); // step 2
  const reference = driverReference.data, own = source.data, expressive = new Float64Array(136);
  for (let i = 0; i < 136; i += 2) { // steps 3-4
    const dx = unmoved[i] - reference[i], dy = unmoved[i + 1] - reference[i + 1];
    expressive[i] = own[i] + (dx * p00 + dy * p01);
    expressive[i + 1] = own[i + 1] + (dx * p10 + dy * p11);
  }
  const moved = applySim(applySim(applySim(expressive, unplace), motion), place); // step 5: P^-1, H_t, P
  return tensor(moved, [68, 2]);
}

/** What a live stream drives the subject with, one frame (landmarks.motion.retarget_points.retarget_driving): retargetRelative,
 * then the mouth as open as the driver's, then the lids as closed as the driver's in proportion, against
 * `referenceGaps` (2,) (DriverReference.lids; null: lidGaps of driverReference). (68, 2) each -> (68, 2). */
export function retargetDriving(driver: Tensor, driverReference: Tensor, source: Tensor,
                                referenceGaps: Tensor | ArrayLike<number> | null = null): Tensor<Float64Array> {
  const moved = retargetRelative(driver, driverReference, source);
  if (!finite(driver.data)) return moved;
  const output = setMouthOpening(moved, mouthOpening(driver.data));
  const gaps = referenceGaps === null ? lidGaps(driverReference.data) : flat(referenceGaps);
  lidsAsDriverInPlace(output.data, driver.data, gaps, source.data);
  return output;
}

/** LiveSession.prepare's steps after the tracker, one frame: the reference lid gaps of the face as detected
 * (`points`, frame pixels; `gaps`, when the caller read them already), the crop of the smoothed face (`smoothed`: LiveSmoother.step's, or `points` unsmoothed),
 * the reference face started, then retargetDriving onto the subject's anchor (`subjectReference`, crop pixels)
 * -> the target (68, 2) in crop pixels. */
export function liveTarget(reference: DriverReference, points: Tensor, smoothed: Tensor, cropSize: number,
                           subjectReference: Tensor, gaps = reference.lids(points)): Tensor<Float64Array> {
  const crop = transformPoints(smoothed, cropTransform(smoothed, cropSize));
  reference.start(crop);
  return retargetDriving(crop, reference.landmarks as Tensor<Float64Array>, subjectReference, gaps);
}

/** A whole driver track through liveTarget, for tests: points (T, 68, 2) frame pixels as detected (a non-finite frame
 * = no face: skipped, a NaN row out); smoothed: (T, 68, 2) the same frames smoothed, or null to crop the points as
 * they are; recentreAt: frame indices before which DriverReference.reset runs (LiveSession.recentre)
 * -> (T, 68, 2) targets. */
export function retargetSequence(points: Tensor, cropSize: number, subjectReference: Tensor,
                                 smoothed: Tensor | null = null, recentreAt: number[] = []): Tensor<Float64Array> {
  if (points.shape.length !== 3 || points.shape[1] !== 68 || points.shape[2] !== 2) {
    throw new Error(`points must be (T, 68, 2), got [${points.shape}]`);
  }
  const frames = points.shape[0], size = 136, out = new Float64Array(frames * size);
  const reference = new DriverReference();
  for (let t = 0; t < frames; t++) {
    if (recentreAt.includes(t)) reference.reset();
    const frame = tensor(points.data.subarray(t * size, (t + 1) * size), [68, 2]);
    if (!finite(frame.data)) {
      out.fill(NaN, t * size, (t + 1) * size);
      continue;
    }
    const cropped = smoothed === null ? frame : tensor(smoothed.data.subarray(t * size, (t + 1) * size), [68, 2]);
    out.set(liveTarget(reference, frame, cropped, cropSize, subjectReference).data, t * size);
  }
  return tensor(out, [frames, 68, 2]);
}
