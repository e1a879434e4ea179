// The irises as a gaze (issue 40: one iris, where the driver looks): landmarks/parts/eyes/iris.py (EYES, CLOSED, eye_axes,
// find_irises, gaze_offsets, retarget_gaze) and lsr/core/finish.py (shot_irises, DriverGaze). The iris net is the
// tracker's (facemesh.ts FaceMesh, landmarks.detect.mediapipe_mesh's), on the same 64x64 eye squares, here levelled on each eye's
// corners of the 68 points. Irises travel as (2, 4) flat rows [x, y, radius, aperture], image-left eye first (the
// tracker's `irises`); a gaze as (2, 2) flat [along the corner line, across it (down)] in eye widths, NaN where none.

import { EYE_ROI_SCALE, FaceMesh, eyeCrop, eyeIris } from "./facemesh.js";
import { invertAffine } from "./geometry.js";
import { Tensor, columnMedian, median, tensor } from "./tensor.js";
import { createTracker, readTrackerAssets } from "./tracker.js";

/** Per eye of the 68 points, image left first: its corners and whether the iris net sees it mirrored
 * (landmarks.parts.eyes.iris.EYES). */
export const IRIS_EYES: [number, number, boolean][] = [[36, 39, false], [42, 45, true]];
/** A driver's eye whose lid gap by the iris net is below this fraction of its gap when open is closing: no gaze
 * (landmarks.parts.eyes.iris.CLOSED). */
export const CLOSED = 0.8;

export interface EyeAxes { centre: [number, number]; axis: [number, number]; width: number }

/** Centre, unit axis along the corners and width of eye `eye` (0 = image left) of (68, 2) points, flat
 * (landmarks.parts.eyes.iris.eye_axes). */
export function eyeAxes(landmarks: ArrayLike<number>, eye: number): EyeAxes {
  const [first, last] = IRIS_EYES[eye];
  const sx = landmarks[2 * first], sy = landmarks[2 * first + 1];
  const ex = landmarks[2 * last], ey = landmarks[2 * last + 1];
  const dx = ex - sx, dy = ey - sy, width = Math.sqrt(dx * dx + dy * dy), scale = Math.max(width, 1e-9);
  return { centre: [(sx + ex) / 2, (sy + ey) / 2], axis: [dx / scale, dy / scale], width };
}

function values(array: Tensor | ArrayLike<number>): ArrayLike<number> {
  return "data" in array && "shape" in array ? (array as Tensor).data : (array as ArrayLike<number>);
}

/** Irises (2, 4) and 68 points -> the gaze (2, 2) flat float64 (landmarks.parts.eyes.iris.gaze_offsets): each iris centre from
 * its eye's centre, along and across the corner line, in eye widths; NaN where not found, or where the eye is closing
 * (its aperture below CLOSED x openApertures (2,), e.g. the median over the person's frames). */
export function gazeOffsets(irises: Tensor | ArrayLike<number>, landmarks: Tensor | ArrayLike<number>,
                            openApertures: Tensor | ArrayLike<number> | null = null): Float64Array {
  const rows = values(irises), points = values(landmarks), offsets = new Float64Array(4).fill(NaN);
  const open = openApertures === null ? null : values(openApertures);
  for (let eye = 0; eye < 2; eye++) {
    const x = rows[4 * eye], y = rows[4 * eye + 1], radius = rows[4 * eye + 2], aperture = rows[4 * eye + 3];
    if (!(Number.isFinite(x) && Number.isFinite(y) && Number.isFinite(radius))) continue;
    if (open !== null && !(aperture >= CLOSED * open[eye])) continue;
    const { centre, axis, width } = eyeAxes(points, eye);
    if (width < 1) continue;
    const dx = x - centre[0], dy = y - centre[1];
    offsets[2 * eye] = (dx * axis[0] + dy * axis[1]) / width;
    offsets[2 * eye + 1] = (dx * -axis[1] + dy * axis[0]) / width;
  }
  return offsets;
}

/** Relative gaze (landmarks.parts.eyes.iris.retarget_gaze): the source's own (its anchor shot's gaze) moved by the driver's
 * since its reference frame, (2, 2) flat each; where the reference or the source has no gaze (NaN), the driver's own
 * (absolute) offsets are kept. */
export function retargetGaze(driver: Tensor | ArrayLike<number>, driverReference: Tensor | ArrayLike<number>,
                             source: Tensor | ArrayLike<number>): Float64Array {
  const reference = values(driverReference), own = values(source);
  const driven = values(driver), out = new Float64Array(driven.length);
  for (let i = 0; i < driven.length; i++) {
    const shift = own[i] - reference[i];
    out[i] = driven[i] + (Number.isFinite(shift) ? shift : 0);
  }
  return out;
}

/** A driver's gaze, frame by frame, as the target's (lsr.core.finish.DriverGaze): `source` null, its own (absolute);
 * else `source` (2, 2) flat (the subject's anchor gaze) moved by the driver's since its first frame whose irises were
 * found (retargetGaze), as relative motion moves the 68 points. An eye is closing (no gaze) against the median of its
 * last HISTORY apertures. */
export class DriverGaze {
  static readonly HISTORY = 150;
  reference: Float64Array | null = null;
  private apertures: [number, number][] = [];

  constructor(readonly source: ArrayLike<number> | null) {}

  /** The tracker's irises (2, 4) flat (null: none) and the frame's 68 points -> the target's gaze (2, 2) flat.
   * Python finds the irises itself where the tracker's are not finite (find_irises); here the tracker's side does
   * (trackedIrises), and null stands for none found. */
  update(irises: ArrayLike<number> | null, points: Tensor | ArrayLike<number>): Float64Array {
    const rows = irises ?? new Float64Array(8).fill(NaN);
    if (Number.isFinite(rows[3]) && Number.isFinite(rows[7])) {
      this.apertures = [...this.apertures, [rows[3], rows[7]] as [number, number]].slice(-DriverGaze.HISTORY);
    }
    const open = this.apertures.length
      ? [columnMedian(this.apertures, 0), columnMedian(this.apertures, 1)] : null;
    const gaze = gazeOffsets(rows, points, open);
    if (this.source === null) return gaze;
    if (this.reference === null && gaze.every(Number.isFinite)) this.reference = gaze;
    return this.reference === null ? gaze : retargetGaze(gaze, this.reference, this.source);
  }
}

// ---- the iris net on the 68 points' eyes -----------------------------------------------------------------------

/** Each eye's iris in `image` ((H, W, 3) uint8 RGB) with 68 points `landmarks` in its pixels -> (2, 4) flat float64
 * [x, y, radius, aperture] by the iris net (landmarks.parts.eyes.iris.find_irises; the two eyes one after the other here); NaN
 * rows where the points are not finite or an eye has no width. */
export async function findIrises(faceMesh: FaceMesh, image: Tensor<Uint8Array>, landmarks: Tensor | ArrayLike<number>
                                 ): Promise<Float64Array> {
  const points = values(landmarks), irises = new Float64Array(8).fill(NaN);
  if (points.length !== 136 || !Array.prototype.every.call(points, Number.isFinite)) return irises;
  for (let eye = 0; eye < 2; eye++) {
    const { centre, axis, width } = eyeAxes(points, eye), mirrored = IRIS_EYES[eye][2];
    if (width < 1) continue;
    const region = { centre, side: width * EYE_ROI_SCALE, rotation: Math.atan2(axis[1], axis[0]) };
    const { eye: eyePoints, iris } = await faceMesh.irisOutputs(faceMesh.eyeInput(image, region, mirrored));
    irises.set(eyeIris(eyePoints, iris, invertAffine(eyeCrop(region)), mirrored), 4 * eye);
  }
  return irises;
}

/** The irises DriverGaze reads for a tracked frame: the tracker's own (the mesh tracker runs the iris net on the same
 * eyes), else found with its iris net (findIrises), as lsr.core.finish.DriverGaze does; null without either. */
export async function trackedIrises(tracker: { irises?: Float64Array | null; faceMesh?: FaceMesh },
                                    frame: Tensor<Uint8Array>, points: Tensor): Promise<Float64Array | null> {
  const own = tracker.irises ?? null;
  if (own !== null && own.every(Number.isFinite)) return Float64Array.from(own);
  return tracker.faceMesh ? findIrises(tracker.faceMesh, frame, points) : own && Float64Array.from(own);
}

/** Each shot's iris centres (K, 2, 2) flat from their irises (K, 2, 4) flat: NaN where not found or where the eye is
 * closing against its median aperture over the shots (CLOSED) (lsr.core.finish.shot_irises, after find_irises). */
export function shotIrisCentres(irises: Tensor | ArrayLike<number>): Float64Array {
  const rows = values(irises), count = rows.length / 8, centres = new Float64Array(count * 4);
  for (let k = 0; k < count; k++) {
    for (let eye = 0; eye < 2; eye++) {
      centres[4 * k + 2 * eye] = rows[8 * k + 4 * eye];
      centres[4 * k + 2 * eye + 1] = rows[8 * k + 4 * eye + 1];
    }
  }
  const apertures = (eye: number) => Array.from({ length: count }, (_, k) => rows[8 * k + 4 * eye + 3]);
  if (![0, 1].some((eye) => apertures(eye).some(Number.isFinite))) return centres;
  for (let eye = 0; eye < 2; eye++) {
    const found = apertures(eye).filter(Number.isFinite);
    const opened = found.length ? median(found) : NaN;  // np.nanmedian
    apertures(eye).forEach((aperture, k) => {
      if (!(aperture >= CLOSED * opened)) centres[4 * k + 2 * eye] = centres[4 * k + 2 * eye + 1] = NaN;
    });
  }
  return centres;
}

/** A subject's shots (K, C, C, 3) uint8 with their (K, 68, 2) points -> (K, 2, 4) flat: each shot's findIrises. */
export async function findShotIrises(faceMesh: FaceMesh, shots: Tensor<Uint8Array>, shotLandmarks: Tensor
                                     ): Promise<Float64Array> {
  const [count, height, width] = shots.shape, size = height * width * 3, irises = new Float64Array(count * 8);
  for (let k = 0; k < count; k++) {
    const shot = tensor(shots.data.subarray(k * size, (k + 1) * size), [height, width, 3]);
    irises.set(await findIrises(faceMesh, shot, shotLandmarks.data.subarray(k * 136, (k + 1) * 136)), 8 * k);
  }
  return irises;
}

/** Node, for the tests: the shots' irises with the iris net of a landmarks/assets folder -> { irises (K, 2, 4),
 * centres (K, 2, 2) (shot_irises) }. */
export async function shotIrisesFromAssets(assetsFolder: string, shots: Tensor<Uint8Array>, shotLandmarks: Tensor) {
  const tracker = await createTracker(await readTrackerAssets(assetsFolder));
  const irises = await findShotIrises(tracker.faceMesh, shots, shotLandmarks), count = shots.shape[0];
  return { irises: tensor(irises, [count, 2, 4]), centres: tensor(shotIrisCentres(irises), [count, 2, 2]) };
}

/** Node, for the tests: DriverGaze (source (2, 2) or null) over a sequence of irises (T, 2, 4) and 68 points
 * (T, 68, 2), its reference forgotten before the frames in `recentreAt` -> the gazes (T, 2, 2). */
export function driverGazes(source: Tensor | null, irises: Tensor, landmarks: Tensor, recentreAt: number[] = []
                            ): Tensor<Float64Array> {
  const count = irises.shape[0], gazes = new Float64Array(count * 4);
  const driver = new DriverGaze(source === null ? null : source.data);
  for (let t = 0; t < count; t++) {
    if (recentreAt.includes(t)) driver.reference = null;
    gazes.set(driver.update(irises.data.subarray(8 * t, 8 * (t + 1)), landmarks.data.subarray(136 * t, 136 * (t + 1))),
              4 * t);
  }
  return tensor(gazes, [count, 2, 2]);
}
