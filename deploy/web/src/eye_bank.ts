// The person's own eyes, from every frame they give (issue 63): landmarks/parts/eyes/eye_bank.py (eye_affine,
// eye_corners, cut_eyes, head_turn, eye_state, eye_row, eye_bank_of, build_eye_bank, state_cost, EyeBankTrack,
// paste_bank_eyes, lid_stretch, _placed), with landmarks.shape.measures.eye_apertures. The page lays one real frame's
// eyes over each synthesised face, as the live session does after the parts' other steps (lsr/core/finish.py
// finish_parts):
//
// * the bank: per frame of the person (the example person's video, written by `lsr export --web`; a user's own
//   photos, cut here), both eyes cut into the eye's own frame (eyeAffine: the corner line levelled, CANON_WIDTH
//   pixels corner to corner, bilinear as cv2.warpAffine, remap.ts warpAffineLinear) with each eye's aperture, its
//   gaze (gaze.ts gazeOffsets) and the head's yaw and pitch (pose.ts, read in the face's own crop);
// * the track: per frame, in order, the entry nearest the target's state (stateCost), one entry for both eyes, kept
//   until another is clearly nearer and cross-faded in when it changes (hysteresis.ts). An entry whose lid opening
//   reaches the target's within STRETCH is shown where there is one; an eye opened or shut further than every entry
//   shows takes the nearest extreme, and where it is shut further, the lids are drawn down over it afterwards
//   (EyeChoice.shut; session.ts, as lsr.core.finish.finish_parts). With a reference (the subject's anchor face: the
//   live session's targets are retargeted from a driver), the opening asked is the driver's own lid motion, its
//   small motions' gain undone (retarget.ts driverShare);
// * the paste: each chosen eye mapped onto the target's corners, its opening stretched toward the target's by at
//   most STRETCH (its lids alone: lidStretch), its iris moved along the eye to the target's gaze (iris_warp.ts
//   shiftIris), bicubic (remap_wasm.ts remapImage), lit as the skin around it (interior.ts matchLight, skin on skin) and
//   laid in under the feathered ellipse of eyes.ts (its FEATHER and RING, this module's REGION).
//
// The module's CANON_WIDTH, PATCH, SCALES, STRETCH, NEAREST, LID_BAND and REGION are BANK_CANON_WIDTH, ... here.

import { BankRows, usableFace } from "./bank_rows.js";
import { folderReader } from "./files.js";
import { EYE_FEATHER, EYE_RING, ellipseMask } from "./eyes.js";
import { eyeAxes, gazeOffsets } from "./gaze.js";
import { cropTransform, transformPoints } from "./geometry.js";
import { EntryTrack } from "./hysteresis.js";
import { checkLandmarks, matchLight } from "./interior.js";
import { shiftIris } from "./iris_warp.js";
import { estimateHeadPose } from "./pose.js";
import { gaussianBlurF32, openCvInverse, roundHalfEven, warpAffineLinear } from "./remap.js";
import { remapImage } from "./remap_wasm.js";
import { closedGap, driverShare, finite, flat, interOcularDistance, lidGaps } from "./retarget.js";
import { Affine, Tensor, percentile, tensor } from "./tensor.js";

/** An eye's width (corner to corner) in the bank's patches, in pixels. */
export const BANK_CANON_WIDTH = 32.0;
/** A bank patch's (width, height) in pixels, centred between the eye's corners. */
export const BANK_PATCH: [number, number] = [72, 52];
/** How far apart two states are (stateCost): each term's difference over its scale, squared, summed. */
export const BANK_SCALES = { aperture: 0.04, gaze: 0.06, yaw: 8.0, pitch: 8.0 };
/** An entry's lid opening is stretched onto the target's by at most this factor (or its inverse); where the target
 * shuts further, the lids are drawn over the entry's eye (EyeChoice.shut). */
export const BANK_STRETCH = 1.3;
/** An eye that no entry shows within STRETCH takes the entries whose stretch lies within this factor of the least
 * one's (NEAREST). */
export const BANK_NEAREST = 1.1;
/** A bank eye's iris is moved toward the target's gaze only within these percentiles of the gazes the bank shows
 * (GAZE_SPAN, gazeSpan). */
export const BANK_GAZE_SPAN: [number, number] = [2.0, 98.0];
/** Where a bank eye's lid opening is stretched (lidStretch): wholly within this share of the entry's own aperture of
 * the corner line, fading to nothing over the next this many eye widths (LID_BAND). */
export const BANK_LID_BAND: [number, number] = [0.75, 0.25];
/** The two eyes are shut together (shutBeyondEntry) unless the target's lid openings, each over its entry's, differ
 * by more than this: a wink (WINK). */
export const BANK_WINK = 0.5;
/** The ellipse laid in over each eye: semi-axes along and across the corner line, in eye widths. */
export const BANK_REGION: [number, number] = [1.0, 0.6];
/** The crop side the head's turn is read in (eye_bank.POSE_CROP). */
export const POSE_CROP = 256;
/** build_eye_bank's default bound on the entries. */
export const BANK_MAX_ENTRIES = 600;
/** Each eye's corners of the 68 points, image left first (landmarks.shape.measures.EYES). */
const BANK_CORNERS: [number, number][] = [[36, 39], [42, 45]];
/** Each eye's lid polygon of the 68 points (landmarks.shape.measures.EYE_RINGS). */
const EYE_RINGS = [[36, 37, 38, 39, 40, 41], [42, 43, 44, 45, 46, 47]];

const f32 = Math.fround;

/** A person's eyes, indexed (landmarks.parts.eyes.eye_bank.EyeBank). N entries, each both eyes of one frame. */
export interface EyeBank {
  /** (N, 2, PATCH[1], PATCH[0], 3) uint8 RGB: each entry's eyes (image left first) in the eye's own frame. */
  patches: Tensor<Uint8Array>;
  /** (N, 2) float64: each eye's lid gap over its width (eyeApertures). */
  apertures: Tensor<Float64Array>;
  /** (N, 2, 2) float64: each eye's gaze (gaze.ts gazeOffsets), NaN where not found. */
  gazes: Tensor<Float64Array>;
  /** (N, 2) float64: the head's yaw and pitch in degrees. */
  poses: Tensor<Float64Array>;
}

/** The bank's shapes checked (EyeBank.__post_init__): `bank` itself, or an Error that says which part is wrong. */
export function checkEyeBank(bank: EyeBank): EyeBank {
  const n = bank.patches.shape[0], [w, h] = BANK_PATCH, shape = bank.patches.shape;
  if (shape.length !== 5 || shape[1] !== 2 || shape[2] !== h || shape[3] !== w || shape[4] !== 3
      || !(bank.patches.data instanceof Uint8Array)) {
    throw new Error(`patches must be (N, 2, ${h}, ${w}, 3) uint8, got [${shape}]`);
  }
  const rows = (t: Tensor, size: number) => t.data.length === n * size && t.shape[0] === n;
  if (!rows(bank.apertures, 2) || !rows(bank.gazes, 4) || !rows(bank.poses, 2)) {
    throw new Error("an eye bank's apertures, gazes and poses must hold one row per patch");
  }
  return bank;
}

/** The number of entries of a bank. */
export function bankSize(bank: EyeBank): number {
  return bank.patches.shape[0];
}

/** The (2, 3) affine taking image pixels to an eye's own frame (eye_affine): the corners [x0, y0, x1, y1] (image-left
 * corner first) onto the patch's centre line, CANON_WIDTH apart, around the centre of a patch of `size` (width,
 * height). */
export function eyeAffine(corners: Tensor | ArrayLike<number>, size: [number, number] = BANK_PATCH): Affine {
  const c = flat(corners), alongX = c[2] - c[0], alongY = c[3] - c[1];
  const width = Math.hypot(alongX, alongY);
  if (!(width > 0)) throw new Error("an eye's corners must be apart");
  const ux = alongX / width, uy = alongY / width, scale = BANK_CANON_WIDTH / width;
  // image offsets -> patch offsets: along the corners, then across them (down in the image for a level eye)
  const l00 = ux * scale, l01 = uy * scale, l10 = -uy * scale, l11 = ux * scale;
  const cx = (c[0] + c[2]) / 2, cy = (c[1] + c[3]) / 2;
  return [l00, l01, size[0] / 2.0 - (l00 * cx + l01 * cy), l10, l11, size[1] / 2.0 - (l10 * cx + l11 * cy)];
}

/** (2, 2, 2) flat: each eye's two corners (image left first) of (68, 2) points (eye_corners). */
export function eyeCorners(landmarks: Tensor | ArrayLike<number>): Float64Array {
  const p = flat(landmarks), corners = new Float64Array(8);
  for (let e = 0; e < BANK_CORNERS.length; e++) {
    const [first, last] = BANK_CORNERS[e];
    corners[4 * e] = p[2 * first]; corners[4 * e + 1] = p[2 * first + 1];
    corners[4 * e + 2] = p[2 * last]; corners[4 * e + 3] = p[2 * last + 1];
  }
  return corners;
}

function cornerWidth(corners: ArrayLike<number>, eye: number): number {
  return Math.hypot(corners[4 * eye + 2] - corners[4 * eye], corners[4 * eye + 3] - corners[4 * eye + 1]);
}

/** Both eyes of `frame` (H, W, 3) uint8 with 68 points in its pixels, each in its own frame (eyeAffine) -> (2,
 * size[1], size[0], 3) uint8 (cut_eyes: bilinear, the frame's edge replicated; OpenCV's INTER_AREA for a wide eye is
 * bilinear in warpAffine too). */
export function cutEyes(frame: Tensor<Uint8Array>, landmarks: Tensor | ArrayLike<number>,
                        size: [number, number] = BANK_PATCH): Tensor<Uint8Array> {
  if (frame.shape.length !== 3 || frame.shape[2] !== 3) throw new Error(`frame must be (H, W, 3), got [${frame.shape}]`);
  const corners = eyeCorners(landmarks), [w, h] = size, out = new Uint8Array(2 * h * w * 3);
  const source = { data: frame.data, height: frame.shape[0], width: frame.shape[1], channels: 3 };
  for (let eye = 0; eye < 2; eye++) {
    const matrix = openCvInverse(eyeAffine(corners.subarray(4 * eye, 4 * eye + 4), size));
    out.set(warpAffineLinear(source, matrix, w, h, "replicate"), eye * h * w * 3);
  }
  return tensor(out, [2, h, w, 3]);
}

/** Yaw and pitch in degrees of finite (68, 2) points, read in the face's own crop (POSE_CROP), so that a full
 * frame's face and a crop's read alike (head_turn). */
export function headTurn(landmarks: Tensor | ArrayLike<number>): [number, number] {
  const points = tensor(Float64Array.from(flat(landmarks)), [68, 2]);
  const crop = transformPoints(points, cropTransform(points, POSE_CROP));
  const [yaw, pitch] = estimateHeadPose(crop, POSE_CROP, POSE_CROP);
  return [yaw, pitch];
}

/** (2,) each eye's lid gap (the mean of its two vertical point pairs) over its width, of (68, 2) points
 * (landmarks.shape.measures.eye_apertures). */
export function eyeApertures(landmarks: Tensor | ArrayLike<number>): Float64Array {
  const p = flat(landmarks), apertures = new Float64Array(2);
  for (let eye = 0; eye < EYE_RINGS.length; eye++) {
    const ring = EYE_RINGS[eye], { width } = eyeAxes(p, eye);
    apertures[eye] = (pointGap(p, ring[1], ring[5]) + pointGap(p, ring[2], ring[4])) / 2 / Math.max(width, 1e-9);
  }
  return apertures;
}

/** The distance between points a and b of (68, 2) flat `p`. */
function pointGap(p: ArrayLike<number>, a: number, b: number): number {
  const dx = p[2 * a] - p[2 * b], dy = p[2 * a + 1] - p[2 * b + 1];
  return Math.sqrt(dx * dx + dy * dy);
}

/** What a face's eyes show (eye_state): 68 points (its pixels) and its irises ((2, 4) flat, gaze.ts findIrises rows,
 * or null) -> apertures (2,), gazes (2, 2) flat (NaN without irises), yaw and pitch. */
export interface EyeState { apertures: Float64Array; gazes: Float64Array; pose: [number, number] }

export function eyeState(landmarks: Tensor | ArrayLike<number>, irises: Tensor | ArrayLike<number> | null): EyeState {
  const points = flat(landmarks);
  const gazes = irises === null ? new Float64Array(4).fill(NaN) : gazeOffsets(irises, points);
  return { apertures: eyeApertures(points), gazes, pose: headTurn(points) };
}

/** One frame's entry of an eye bank (eye_row). */
export interface EyeRow extends EyeState { patches: Tensor<Uint8Array> }

/** One frame's entry: the frame (H, W, 3) uint8, its 68 points (null or not finite: no face) and irises ((2, 4) or
 * null) -> its row, or null where it has no face or an eye is under 4 pixels wide. */
export function eyeRow(frame: Tensor<Uint8Array>, points: Tensor | null, irises: Tensor | ArrayLike<number> | null
                       ): EyeRow | null {
  const face = usableFace(frame, points);
  if (face === null) return null;
  const corners = eyeCorners(face);
  if (Math.min(cornerWidth(corners, 0), cornerWidth(corners, 1)) < 4.0) return null;
  return { patches: cutEyes(frame, face), ...eyeState(face, irises) };
}

/** eyeRows -> an EyeBank (null for no rows) (eye_bank_of). */
export function eyeBankOf(rows: EyeRow[]): EyeBank | null {
  if (!rows.length) return null;
  const n = rows.length, size = rows[0].patches.data.length, patches = new Uint8Array(n * size);
  const apertures = new Float64Array(2 * n), gazes = new Float64Array(4 * n), poses = new Float64Array(2 * n);
  rows.forEach((row, i) => {
    patches.set(row.patches.data, i * size);
    apertures.set(row.apertures, 2 * i);
    gazes.set(row.gazes, 4 * i);
    poses.set(row.pose, 2 * i);
  });
  return { patches: tensor(patches, [n, ...rows[0].patches.shape]), apertures: tensor(apertures, [n, 2]),
           gazes: tensor(gazes, [n, 2, 2]), poses: tensor(poses, [n, 2]) };
}

/** One of a person's frames: (H, W, 3) uint8 RGB, its 68 points in its pixels (null or not finite: no face) and its
 * irises ((2, 4) rows, or null). */
export type BankFace = [Tensor<Uint8Array>, Tensor | null, Tensor | ArrayLike<number> | null];

/** The eye bank of a person's frames, read one at a time (build_eye_bank), or null when no frame has a face whose
 * eyes are at least 4 pixels wide. At most `maxEntries` entries, evenly spread over the frames. */
export function buildEyeBank(faces: Iterable<BankFace>, maxEntries = BANK_MAX_ENTRIES): EyeBank | null {
  const rows = new BankRows<EyeRow>(maxEntries);
  for (const [frame, points, irises] of faces) rows.add(eyeRow(frame, points, irises));
  return eyeBankOf(rows.spread());
}

const orZero = (value: number) => (Number.isFinite(value) ? value : 0.0);  // an unknown term: 0
const square = (value: number) => value * value;

/** (N,) how far each entry's state lies from the target's (state_cost): apertures (2,), gazes (2, 2) flat or null
 * (not asked), yaw and pitch (2,). A gaze term counts only where both gazes are known; an entry's unknown aperture or
 * pose costs as much as a far one. */
export function stateCost(bank: EyeBank, apertures: ArrayLike<number>, gazes: ArrayLike<number> | null,
                          pose: ArrayLike<number>): Float64Array {
  const n = bankSize(bank), a = bank.apertures.data, g = bank.gazes.data, p = bank.poses.data;
  const cost = new Float64Array(n);
  const poseScales = [BANK_SCALES.yaw, BANK_SCALES.pitch];
  for (let i = 0; i < n; i++) {
    let value = square((a[2 * i] - apertures[0]) / BANK_SCALES.aperture)
      + square((a[2 * i + 1] - apertures[1]) / BANK_SCALES.aperture);
    value += orZero(square((p[2 * i] - pose[0]) / poseScales[0])) + orZero(square((p[2 * i + 1] - pose[1]) / poseScales[1]));
    if (gazes !== null) {
      let gazeTerms = 0;
      for (let k = 0; k < 4; k++) gazeTerms += orZero(square((g[4 * i + k] - gazes[k]) / BANK_SCALES.gaze));
      value += gazeTerms;
    }
    cost[i] = Number.isFinite(value) ? value : Infinity;
  }
  return cost;
}

/** An output frame's eyes from the bank (EyeChoice): the entry, and the entry it fades from (with that one's weight). */
export interface EyeChoice {
  entry: number;
  previous: number | null;
  previousWeight: number;
  /** Which eyes (image left first) take the bank's: false where the bank has no reading of it, or where no one entry
   * shows both eyes' openings and the other eye's is shown. */
  eyes: [boolean, boolean];
  /** The apertures asked of each eye (EyeBankTrack.asked), which its lid opening is stretched toward. */
  apertures: [number, number];
  /** Where each iris is moved, along the corner line in eye widths (the target's gaze; NaN: left where it is). */
  gazes: [number, number];
  /** Which eyes the target shuts further than the entry's lids stretch (STRETCH): the lids are drawn down over the
   * entry's. */
  shut: [boolean, boolean];
  /** The bank it was chosen from: what pasteBankEyes lays in when given no other (null: none). */
  bank: EyeBank | null;
}

/** Each eye's (least, most) gaze along its corner line that the bank's entries show, flat (2, 2): BANK_GAZE_SPAN's
 * percentiles, NaN where no entry's iris of that eye was read (gaze_span). */
export function gazeSpan(bank: EyeBank): Float64Array {
  const n = bankSize(bank), g = bank.gazes.data, span = new Float64Array(4).fill(NaN);
  for (let eye = 0; eye < 2; eye++) {
    const known = Array.from({ length: n }, (_, i) => g[4 * i + 2 * eye]).filter(Number.isFinite);
    if (known.length > 0) BANK_GAZE_SPAN.forEach((q, k) => { span[2 * eye + k] = percentile(known, q); });
  }
  return span;
}

/** Which of `n` bank entries show the openings asked for the eyes `which` takes ((N, 2) flat `shows`). */
function usableEntries(shows: boolean[], which: boolean[], n: number): boolean[] {
  const usable: boolean[] = new Array(n);
  for (let i = 0; i < n; i++) usable[i] = (!which[0] || shows[2 * i]) && (!which[1] || shows[2 * i + 1]);
  return usable;
}

/** One driven sequence's choice of bank entries, frame by frame (EyeBankTrack; the module comment).
 *
 * reference: the subject's face at rest ((68, 2), the anchor shot's), where the target's lids were retargeted from a
 * driver (relative motion): a real eye follows the driver's own lid motion (driverShare). null: the target's lids as
 * they are. */
export class EyeBankTrack {
  readonly reference: ArrayLike<number> | null;
  readonly entries = new EntryTrack();
  readonly gazeSpan: Float64Array;

  constructor(readonly bank: EyeBank, reference: Tensor | ArrayLike<number> | null = null) {
    checkEyeBank(bank);
    const points = reference === null ? null : flat(reference);
    if (points !== null && points.length !== 136) throw new Error(`reference must be (68, 2), got ${points.length} values`);
    this.reference = points !== null && finite(points) ? Float64Array.from(points) : null;
    this.gazeSpan = gazeSpan(bank);
  }

  /** An eye's gaze clipped to the bank's gazeSpan (NaN stays NaN; an eye the bank has no gaze of, as it is). */
  withinSpan(gaze: number, eye: number): number {
    const [least, most] = [this.gazeSpan[2 * eye], this.gazeSpan[2 * eye + 1]];
    const known = Number.isFinite(least) && Number.isFinite(most) && !Number.isNaN(gaze);
    return known ? Math.min(Math.max(gaze, least), most) : gaze;
  }

  /** How often the entry changed. */
  get switches(): number {
    return this.entries.switches;
  }

  /** A gap in the face (no target): the next frame chooses afresh. */
  reset(): void {
    this.entries.reset();
  }

  /** (2,) the apertures the target's eyes (68, 2) ask of a real eye: its own, or with a reference, the driver's lid
   * motion undone of lidShare's gain (gaps from the reference's closed gap, in proportion). */
  asked(landmarks: Tensor | ArrayLike<number>): Float64Array {
    const points = flat(landmarks), apertures = eyeApertures(points);
    if (this.reference === null) return apertures;
    const rest = lidGaps(this.reference), gaps = lidGaps(points), out = new Float64Array(2);
    for (let e = 0; e < 2; e++) {
      const shut = closedGap(rest[e]);
      const share = (gaps[e] - shut) / (rest[e] > shut ? rest[e] - shut : NaN);
      const goal = shut + (rest[e] - shut) * driverShare(Math.max(share, 0.0));
      const undone = (apertures[e] * goal) / gaps[e];
      out[e] = Number.isFinite(undone) && gaps[e] > 0 ? undone : apertures[e];
    }
    return out;
  }

  /** The target's 68 points (its pixels) and gaze ((2, 2) flat gazeOffsets, or null) -> this frame's choice, or null
   * where neither eye takes the bank's (EyeBankTrack.__call__). */
  step(landmarks: Tensor, gazes: ArrayLike<number> | null = null): EyeChoice | null {
    const points = checkLandmarks(landmarks);
    if (!finite(points)) {
      this.reset();
      return null;
    }
    const apertures = this.asked(points), n = bankSize(this.bank), own = this.bank.apertures.data;
    // (N, 2): how far each entry's lids would stretch (|log| of the ratio; not known: Infinity). Plain loops here,
    // no closures made per frame (V8 optimised those again on every frame)
    const far = new Float64Array(2 * n), least = [Infinity, Infinity];
    for (let k = 0; k < 2 * n; k++) {
      const value = Math.abs(Math.log(apertures[k % 2] / own[k]));
      far[k] = Number.isFinite(value) ? value : Infinity;
      if (far[k] < least[k % 2]) least[k % 2] = far[k];
    }
    // an entry within STRETCH where there is one; for an eye opened or shut beyond every entry, or between two far
    // apart, the nearest (stretched as far as it goes: placedEye)
    const reach = [0, 0], shows: boolean[] = new Array(2 * n), counts = [0, 0];
    for (let e = 0; e < 2; e++) reach[e] = Math.max(Math.log(BANK_STRETCH), least[e] + Math.log(BANK_NEAREST)) + 1e-9;
    for (let k = 0; k < 2 * n; k++) {
      shows[k] = Number.isFinite(far[k]) && far[k] <= reach[k % 2];
      if (shows[k]) counts[k % 2]++;
    }
    let eyes = [counts[0] > 0, counts[1] > 0];
    if (!eyes[0] && !eyes[1]) {
      this.reset();
      return null;
    }
    let usable = usableEntries(shows, eyes, n);
    if (!usable.includes(true)) {  // no one entry shows both eyes' openings: the eye that more entries show
      const more = counts[1] > counts[0] ? 1 : 0;  // np.argmax: the first of equals
      eyes = [more === 0, more === 1];
      usable = usableEntries(shows, eyes, n);
    }
    const state = stateCost(this.bank, apertures, gazes, headTurn(points));
    const cost = new Float64Array(n);
    for (let i = 0; i < n; i++) cost[i] = usable[i] ? state[i] : Infinity;
    const [entry, previous, previousWeight] = this.entries.step(cost);
    const shut = shutBeyondEntry(apertures, [own[2 * entry], own[2 * entry + 1]], eyes);
    return {
      entry, previous, previousWeight, eyes: [eyes[0], eyes[1]], apertures: [apertures[0], apertures[1]],
      gazes: gazes === null ? [NaN, NaN] : [this.withinSpan(gazes[0], 0), this.withinSpan(gazes[2], 1)],
      shut: [shut[0], shut[1]], bank: this.bank,
    };
  }
}

/** Which of the eyes taking the bank's the target shuts further than their entry's lids stretch (STRETCH), from the
 * apertures asked over the entry's own (eye_bank.shut_beyond_entry): both go by the more shut of the two unless they
 * differ by more than WINK, so one blink is never drawn as a wink. */
export function shutBeyondEntry(apertures: ArrayLike<number>, own: ArrayLike<number>, eyes: boolean[]): boolean[] {
  const ratios = [0, 1].map((e) => (eyes[e] ? apertures[e] / own[e] : NaN));
  const together = ratios.every(Number.isFinite) && Math.abs(ratios[0] - ratios[1]) <= BANK_WINK;
  const least = Math.min(ratios[0], ratios[1]);
  return [0, 1].map((e) => eyes[e] && (together ? least : ratios[e]) < 1.0 / BANK_STRETCH);
}

/** A backward map's rows in an eye's own frame (eyeAffine: the corner line at the patch's middle row), in place, with
 * the eye's lid opening stretched by `stretch` within BANK_LID_BAND of the corner line (`aperture`: the eye's own, in
 * eye widths), fading to the unstretched map beyond it (a smoothstep; lid_stretch). */
export function lidStretch(mapY: Float32Array, stretch: number, aperture: number): void {
  if (stretch === 1.0 || !Number.isFinite(aperture)) return;
  const middle = BANK_PATCH[1] / 2.0, inner = BANK_LID_BAND[0] * aperture * BANK_CANON_WIDTH;
  const band = BANK_LID_BAND[1] * BANK_CANON_WIDTH, squeeze = 1.0 - 1.0 / stretch;
  for (let i = 0; i < mapY.length; i++) {
    const offset = mapY[i] - middle;
    const fade = Math.min(Math.max((Math.abs(offset) - inner) / band, 0.0), 1.0);
    mapY[i] = middle + offset * (1.0 - squeeze * (1.0 - fade * fade * (3.0 - 2.0 * fade)));
  }
}

/** Entry `entry`'s eye `eye` mapped onto the target's 68 points `points` (box pixels, flat): by its corners, its lid
 * opening stretched toward `aperture` within STRETCH (lidStretch), its iris moved along the eye from where the entry
 * looked to `gaze` (NaN: left) -> (box[0], box[1], 3) float32 (_placed). */
export function placedEye(bank: EyeBank, entry: number, eye: number, points: Float64Array, aperture: number,
                          gaze: number, box: [number, number]): Float32Array {
  const own = bank.apertures.data[2 * entry + eye];
  const stretch = own > 0 && Number.isFinite(aperture)
    ? Math.min(Math.max(aperture / own, 1.0 / BANK_STRETCH), BANK_STRETCH) : 1.0;
  const m = eyeAffine(eyeCorners(points).subarray(4 * eye, 4 * eye + 4), BANK_PATCH);  // box -> patch pixels
  const [h, w] = box, mapX = new Float32Array(h * w), mapY = new Float32Array(h * w);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      mapX[y * w + x] = m[0] * x + m[1] * y + m[2];
      mapY[y * w + x] = m[3] * x + m[4] * y + m[5];
    }
  }
  lidStretch(mapY, stretch, own);
  const start = bank.gazes.data[4 * entry + 2 * eye];
  if (Number.isFinite(start) && Number.isFinite(gaze)) {
    shiftIris({ mapX: tensor(mapX, [h, w]), mapY: tensor(mapY, [h, w]) }, tensor(points, [68, 2]), eye, start, gaze);
  }
  const [pw, ph] = BANK_PATCH, size = ph * pw * 3, at = (2 * entry + eye) * size;
  const patch = tensor(bank.patches.data.subarray(at, at + size), [ph, pw, 3]);
  return Float32Array.from(remapImage(patch, tensor(mapX, [h, w]), tensor(mapY, [h, w]), "replicate").data);
}

/** `image` (S, S, 3) uint8, the synthesis for the target's (68, 2) points (its pixels), with the chosen bank eyes laid
 * over its own (paste_bank_eyes): `image` itself when there is no choice or the points are not finite, else a new
 * image (or `image` written in place when inPlace). bank: null, the one the choice was made from. */
export function pasteBankEyes(image: Tensor, landmarks: Tensor, bank: EyeBank | null, choice: EyeChoice | null,
                              inPlace = false): Tensor {
  if (image.shape.length !== 3 || image.shape[2] !== 3 || !(image.data instanceof Uint8Array)) {
    throw new Error(`image must be (H, W, 3) uint8, got [${image.shape}]`);
  }
  const p = checkLandmarks(landmarks);
  const source = bank ?? choice?.bank ?? null;
  if (source === null || choice === null || !finite(p)) return image;
  const ring = Math.max(1, roundHalfEven(EYE_RING * interOcularDistance(p)));
  const ownApertures = eyeApertures(p);
  const apertures = [0, 1].map((e) => (Number.isFinite(choice.apertures[e]) ? choice.apertures[e] : ownApertures[e]));
  const [height, width] = image.shape;
  const out = inPlace ? image : tensor(new Uint8Array(image.data as Uint8Array), [...image.shape]);
  const data = out.data as Uint8Array;
  for (let eye = 0; eye < 2; eye++) {
    const { centre, axis, width: eyeWidth } = eyeAxes(p, eye);
    if (!choice.eyes[eye] || eyeWidth < 2.0) continue;
    const axes: [number, number] = [BANK_REGION[0] * eyeWidth, BANK_REGION[1] * eyeWidth];
    const sigma = Math.max(0.5, EYE_FEATHER * eyeWidth), margin = axes[0] + ring + 3 * sigma + 1;
    const x0 = Math.max(Math.floor(centre[0] - margin), 0), y0 = Math.max(Math.floor(centre[1] - margin), 0);
    const x1 = Math.min(Math.ceil(centre[0] + margin) + 1, width), y1 = Math.min(Math.ceil(centre[1] + margin) + 1, height);
    if (x1 - x0 < 2 || y1 - y0 < 2) continue;
    const w = x1 - x0, h = y1 - y0, box: [number, number] = [h, w];
    const local = new Float64Array(p.length);  // loops, not closures made per frame (V8 optimised each again)
    for (let i = 0; i < p.length; i++) local[i] = p[i] - (i % 2 === 0 ? x0 : y0);
    let warped = placedEye(source, choice.entry, eye, local, apertures[eye], choice.gazes[eye], box);
    if (choice.previous !== null && choice.previousWeight > 0) {
      const fading = placedEye(source, choice.previous, eye, local, apertures[eye], choice.gazes[eye], box);
      const old = f32(choice.previousWeight), kept = f32(1.0 - choice.previousWeight);
      for (let i = 0; i < warped.length; i++) warped[i] = f32(f32(old * fading[i]) + f32(kept * warped[i]));
    }
    const region = new Float32Array(w * h * 3);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w * 3; x++) region[3 * y * w + x] = data[3 * ((y0 + y) * width + x0) + x];
    }
    const inside = ellipseMask(centre[0] - x0, centre[1] - y0, axes, axis[0], axis[1], w, h);
    const laid = matchLight(warped, region, Uint8Array.from(inside), w, h, ring, 1.0, null);  // skin on skin
    const weight = gaussianBlurF32(inside, w, h, 1, sigma);
    for (let y = 0; y < h; y++) {
      for (let x = 0; x < w; x++) {
        const k = y * w + x, wt = weight[k], rest = f32(1.0 - wt), at = 3 * ((y0 + y) * width + x0 + x);
        for (let c = 0; c < 3; c++) {
          const mixed = f32(f32(wt * laid[3 * k + c]) + f32(rest * region[3 * k + c]));
          data[at + c] = Math.min(Math.max(roundHalfEven(mixed), 0), 255);
        }
      }
    }
  }
  return out;
}

// ---- the site's bank (lsr/export/web_site.py write_eye_bank) ------------------------------------------------------

/** The bank of a site's person/ folder through `read`: eye_bank.json (its count and index, NaN written as null) and
 * eye_bank.u8 (the patches, raw). */
export async function readEyeBank(read: (path: string) => Promise<Uint8Array>, folder = "person"): Promise<EyeBank> {
  const index = JSON.parse(new TextDecoder().decode(await read(`${folder}/eye_bank.json`)));
  const count = index.count as number, [w, h] = BANK_PATCH;
  if (!(Number.isInteger(count) && count >= 1) || index.patch?.[0] !== w || index.patch?.[1] !== h) {
    throw new Error(`${folder}/eye_bank.json: a bank of ${w} x ${h} patches expected, got ${JSON.stringify(index.patch)} x ${count}`);
  }
  const values = (name: string, size: number): Float64Array => {
    const flattened = (index[name] as unknown[]).flat(2) as (number | null)[];
    if (flattened.length !== count * size) {
      throw new Error(`${folder}/eye_bank.json: ${count * size} ${name} expected, got ${flattened.length}`);
    }
    return Float64Array.from(flattened, (value) => (value === null ? NaN : value));
  };
  const patches = await read(`${folder}/eye_bank.u8`);
  return checkEyeBank({
    patches: tensor(patches, [count, 2, h, w, 3]), apertures: tensor(values("apertures", 2), [count, 2]),
    gazes: tensor(values("gazes", 4), [count, 2, 2]), poses: tensor(values("poses", 2), [count, 2]),
  });
}

// ---- Node, for the tests --------------------------------------------------------------------------------------------

/** Node: buildEyeBank over frames (T, H, W, 3) with their points (T, 68, 2; a non-finite frame: no face) and irises
 * ((T, 2, 4), or null) -> the bank, or null. */
export function buildEyeBankOfFrames(frames: Tensor<Uint8Array>, points: Tensor, irises: Tensor | null,
                                     maxEntries = BANK_MAX_ENTRIES): EyeBank | null {
  const [count, height, width] = frames.shape, size = height * width * 3;
  function* faces(): Generator<BankFace> {
    for (let t = 0; t < count; t++) {
      yield [tensor(frames.data.subarray(t * size, (t + 1) * size), [height, width, 3]),
             tensor(points.data.subarray(136 * t, 136 * (t + 1)), [68, 2]),
             irises === null ? null : irises.data.subarray(8 * t, 8 * (t + 1))];
    }
  }
  return buildEyeBank(faces(), maxEntries);
}

/** Node: a track over a target sequence (T, 68, 2) (a non-finite frame: no face), with gazes ((T, 2, 2), or null) and
 * the subject's reference (68, 2) or null -> each frame's choice without its bank (null: none), and the switches. */
export function eyeBankChoices(bank: EyeBank, reference: Tensor | null, targets: Tensor, gazes: Tensor | null) {
  const track = new EyeBankTrack(bank, reference), choices = [];
  for (let t = 0; t < targets.shape[0]; t++) {
    const target = tensor(Float64Array.from(targets.data.subarray(136 * t, 136 * (t + 1))), [68, 2]);
    const choice = track.step(target, gazes === null ? null : gazes.data.subarray(4 * t, 4 * (t + 1)));
    choices.push(choice === null ? null : { ...choice, bank: null });
  }
  return { choices, switches: track.switches };
}

/** Node: readEyeBank of the site in `folder`. */
export async function eyeBankFromFolder(folder: string): Promise<EyeBank> {
  return readEyeBank(await folderReader(folder));
}
