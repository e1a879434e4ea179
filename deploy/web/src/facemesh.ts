// MediaPipe's 468-point face mesh and its iris-net eye refinement around their ONNX graphs: landmarks/detect/mediapipe_mesh.py
// (Region.to_crop, region_from_detection, region_from_mesh, predict_mesh, to_frame, eye_region, eye_crop, eye_input,
// iris_outputs, eye_iris, refine_eyes, lid_gap, block_change, IrisGate). Meshes are (468, 3) float32 flat: x, y in
// frame pixels, z at the same scale.
// The crops are sampled like cv2.warpAffine with INTER_LINEAR (bilinear, pixel centres on integers).

import * as ort from "onnxruntime-web";
import { Detection, sigmoid } from "./facedetect.js";
import { Affine, Tensor } from "./tensor.js";
import { invertAffine } from "./geometry.js";

export const MESH_POINTS = 468;
export const MESH_SIZE = 192;
export const ROI_SCALE = 1.5;
export const IRIS_SIZE = 64;
export const EYE_ROI_SCALE = 2.3;
/** Per eye (image left first): the corners levelling its square, the mesh vertices the iris net's first 16 points
 * replace, and whether the crop is mirrored (landmarks.detect.mediapipe_mesh.EYE_CONTOURS). */
export const EYE_CONTOURS: { corners: [number, number]; contour: number[]; mirrored: boolean }[] = [
  { corners: [33, 133], contour: [33, 7, 163, 144, 145, 153, 154, 155, 133, 246, 161, 160, 159, 158, 157, 173], mirrored: false },
  { corners: [362, 263], contour: [263, 249, 390, 373, 374, 380, 381, 382, 362, 466, 388, 387, 386, 385, 384, 398], mirrored: true },
];
export const EYE_CORNERS: [number, number] = [33, 263];

/** A rotated square in the frame (landmarks.detect.mediapipe_mesh.Region): centre, side, rotation (radians, the eye line's angle,
 * clockwise on screen). */
export interface Region { centre: [number, number]; side: number; rotation: number }

/** The affine frame pixels -> size x size crop of a region (landmarks.detect.mediapipe_mesh.Region.to_crop). */
export function regionToCrop(region: Region, size: number): Affine {
  const cos = Math.cos(region.rotation), sin = Math.sin(region.rotation), scale = size / region.side;
  const a = cos * scale, b = sin * scale, d = -sin * scale, e = cos * scale;
  const [cx, cy] = region.centre;
  return [a, b, size / 2 - (a * cx + b * cy), d, e, size / 2 - (d * cx + e * cy)];
}

function levelAngle(sx: number, sy: number, ex: number, ey: number): number {
  return -Math.atan2(-(ey - sy), ex - sx);
}

/** The mesh region of a detection (landmarks.detect.mediapipe_mesh.region_from_detection): the box's longer side x 1.5, levelled on
 * the eye keypoints. */
export function regionFromDetection(detection: Detection): Region {
  const { box, keypoints: k } = detection;
  return {
    centre: [(box[0] + box[2]) / 2, (box[1] + box[3]) / 2],
    side: Math.max(box[2] - box[0], box[3] - box[1]) * ROI_SCALE,
    rotation: levelAngle(k[0], k[1], k[2], k[3]),
  };
}

/** The next frame's region from this frame's mesh (landmarks.detect.mediapipe_mesh.region_from_mesh): the points' extent in the
 * face's levelled axes (outer eye corners), 1.5x its longer side. mesh: (468, 3) flat. */
export function regionFromMesh(mesh: Float32Array): Region {
  const [s, e] = EYE_CORNERS;
  const rotation = levelAngle(mesh[3 * s], mesh[3 * s + 1], mesh[3 * e], mesh[3 * e + 1]);
  const cos = Math.cos(rotation), sin = Math.sin(rotation);
  let lowX = Infinity, lowY = Infinity, highX = -Infinity, highY = -Infinity;
  for (let i = 0; i < MESH_POINTS; i++) {
    const x = mesh[3 * i], y = mesh[3 * i + 1];
    const u = x * cos + y * sin, v = -x * sin + y * cos;
    if (u < lowX) lowX = u; if (u > highX) highX = u;
    if (v < lowY) lowY = v; if (v > highY) highY = v;
  }
  const mu = (lowX + highX) / 2, mv = (lowY + highY) / 2;
  return { centre: [mu * cos - mv * sin, mu * sin + mv * cos], side: Math.max(highX - lowX, highY - lowY) * ROI_SCALE, rotation };
}

/** cv2.warpAffine(image, matrix, (size, size), INTER_LINEAR, BORDER_CONSTANT (0) or BORDER_REPLICATE), each value
 * rounded to uint8 and then scaled by 1/255 into out ((size, size, 3) float32); mirrored: columns reversed. */
export function warpAffineInto(image: Tensor<Uint8Array>, matrix: Affine, size: number, replicate: boolean,
                               mirrored: boolean, out: Float32Array): void {
  const [height, width] = image.shape;
  const data = image.data, stride = width * 3;
  const m = invertAffine(matrix);
  for (let y = 0; y < size; y++) {
    let sx = m[1] * y + m[2], sy = m[4] * y + m[5];
    for (let x = 0; x < size; x++, sx += m[0], sy += m[3]) {
      const o = (y * size + (mirrored ? size - 1 - x : x)) * 3;
      const x0 = Math.floor(sx), y0 = Math.floor(sy);
      const fx = sx - x0, fy = sy - y0;
      const w00 = (1 - fx) * (1 - fy), w01 = fx * (1 - fy), w10 = (1 - fx) * fy, w11 = fx * fy;
      if (x0 >= 0 && y0 >= 0 && x0 + 1 < width && y0 + 1 < height) {
        const p = y0 * stride + x0 * 3, q = p + stride;
        for (let c = 0; c < 3; c++) {
          const v = w00 * data[p + c] + w01 * data[p + 3 + c] + w10 * data[q + c] + w11 * data[q + 3 + c];
          const whole = v | 0;  // v >= 0: Math.round(v), without its cost: the fraction v - whole is exact
          out[o + c] = (v - whole >= 0.5 ? whole + 1 : whole) / 255;
        }
        continue;
      }
      let xa = x0, xb = x0 + 1, ya = y0, yb = y0 + 1;
      let wa = 1, wb = 1, wc = 1, wd = 1; // inside flags of the four taps (constant border: 0 outside)
      if (replicate) {
        xa = clamp(xa, width); xb = clamp(xb, width); ya = clamp(ya, height); yb = clamp(yb, height);
      } else {
        const inXa = xa >= 0 && xa < width ? 1 : 0, inXb = xb >= 0 && xb < width ? 1 : 0;
        const inYa = ya >= 0 && ya < height ? 1 : 0, inYb = yb >= 0 && yb < height ? 1 : 0;
        wa = inXa * inYa; wb = inXb * inYa; wc = inXa * inYb; wd = inXb * inYb;
        xa = clamp(xa, width); xb = clamp(xb, width); ya = clamp(ya, height); yb = clamp(yb, height);
      }
      const p00 = ya * stride + xa * 3, p01 = ya * stride + xb * 3, p10 = yb * stride + xa * 3, p11 = yb * stride + xb * 3;
      for (let c = 0; c < 3; c++) {
        const v = wa * w00 * data[p00 + c] + wb * w01 * data[p01 + c] + wc * w10 * data[p10 + c] + wd * w11 * data[p11 + c];
        out[o + c] = Math.round(v) / 255;
      }
    }
  }
}

function clamp(v: number, n: number): number {
  return v < 0 ? 0 : v >= n ? n - 1 : v;
}

/** (x, y) of a crop's pixels -> frame pixels through the inverse of the frame-to-crop affine (landmarks.detect.mediapipe_mesh.to_frame). */
function toFrame(inverse: Affine, x: number, y: number): [number, number] {
  return [inverse[0] * x + inverse[1] * y + inverse[2], inverse[3] * x + inverse[4] * y + inverse[5]];
}

/** The iris net's square around one eye (landmarks.detect.mediapipe_mesh.eye_region). */
export function eyeRegion(mesh: Float32Array, corners: [number, number]): Region {
  const sx = mesh[3 * corners[0]], sy = mesh[3 * corners[0] + 1], ex = mesh[3 * corners[1]], ey = mesh[3 * corners[1] + 1];
  return { centre: [(sx + ex) / 2, (sy + ey) / 2], side: Math.hypot(ex - sx, ey - sy) * EYE_ROI_SCALE, rotation: levelAngle(sx, sy, ex, ey) };
}

/** The affine into the iris net's 64x64 crop, the region's centre at 31.5 (landmarks.detect.mediapipe_mesh.eye_crop). */
export function eyeCrop(region: Region): Affine {
  const m = regionToCrop(region, IRIS_SIZE);
  m[2] -= 0.5; m[5] -= 0.5;
  return m;
}

/** One mesh prediction (landmarks.detect.mediapipe_mesh.MeshResult): mesh (468, 3) flat float32, presence in [0, 1], the region, and
 * the irises (2, 4) flat [x, y, radius, aperture] per eye (NaN where not run), null when the eyes were not refined. */
export interface MeshResult { mesh: Float32Array; presence: number; region: Region; irises: Float64Array | null }

function outputBySize(outputs: ort.InferenceSession.OnnxValueMapType, names: readonly string[], size: number): Float32Array {
  for (const name of names) {
    const data = outputs[name].data as Float32Array;
    if (data.length === size) return data;
  }
  throw new Error(`no output of ${size} values among ${names.join(", ")}`);
}

/** The gap between an eye contour's lids (corner, 7 lower-lid points, corner, 7 upper-lid points; (16, stride) flat,
 * x and y first in each row): the mean distance of the middle three pairs (landmarks.detect.mediapipe_mesh.lid_gap). */
export function lidGap(contour: ArrayLike<number>, stride = 2): number {
  let total = 0;
  for (let k = 3; k < 6; k++) {
    const lower = stride * k, upper = stride * (k + 8);
    total += Math.hypot(contour[upper] - contour[lower], contour[upper + 1] - contour[lower + 1]);
  }
  return total / 3;
}

const BLOCK = 8;  // the iris gate's blocks: 8 x 8 of the 64 x 64 input

/** The largest mean absolute change between two iris-net inputs ((64, 64, 3) float32 flat in [0, 1]) over the
 * BLOCK x BLOCK pixel blocks of the crop, summed in float64 (landmarks.detect.mediapipe_mesh.block_change). */
export function blockChange(input: Float32Array, last: Float32Array): number {
  const side = IRIS_SIZE / BLOCK, sums = new Float64Array(side * side);
  for (let y = 0, i = 0; y < IRIS_SIZE; y++) {
    const row = Math.floor(y / BLOCK) * side;
    for (let x = 0; x < IRIS_SIZE; x++, i += 3) {
      sums[row + Math.floor(x / BLOCK)] += Math.abs(input[i] - last[i]) + Math.abs(input[i + 1] - last[i + 1])
        + Math.abs(input[i + 2] - last[i + 2]);
    }
  }
  let most = 0;
  for (const sum of sums) most = Math.max(most, sum);
  return most / (BLOCK * BLOCK * 3);
}

/** The iris net's outputs on one eye: its 71 eye points and 5 iris points (x, y, z flat) in its 64x64 crop. */
export interface IrisOutputs { eye: Float32Array; iris: Float32Array }

/** The iris net only where an eye changed (landmarks.detect.mediapipe_mesh.IrisGate; live tracking): an
 * eye whose input changed by less than maxChange (blockChange) and whose mesh lid gap moved by less than maxGapChange
 * crop pixels since its last run takes that run's outputs again, at most maxSkips frames in a row. */
export class IrisGate {
  runs = 0;
  skips = 0;
  private last: ({ input: Float32Array; gap: number; outputs: IrisOutputs } | null)[] = [null, null];
  private streak = [0, 0];

  constructor(readonly maxChange = 0.02, readonly maxGapChange = 0.3, readonly maxSkips = 2) {}

  /** Forget the last runs (a lost face, a new detection): every eye runs next time. */
  reset(): void {
    this.last = [null, null];
    this.streak = [0, 0];
  }

  /** The last run's outputs for `eye` where they still hold for this input and lid gap, else null. */
  kept(eye: number, input: Float32Array, gap: number): IrisOutputs | null {
    const last = this.last[eye];
    if (last === null || this.streak[eye] >= this.maxSkips) return null;
    if (!(Math.abs(gap - last.gap) < this.maxGapChange)) return null;
    if (!(blockChange(input, last.input) < this.maxChange)) return null;
    this.streak[eye] += 1;
    this.skips += 1;
    return last.outputs;
  }

  /** Keep a run of the net on `eye` (its input is kept as it is: pass a copy the caller does not reuse). */
  ran(eye: number, input: Float32Array, gap: number, outputs: IrisOutputs): void {
    this.last[eye] = { input, gap, outputs };
    this.streak[eye] = 0;
    this.runs += 1;
  }
}

/** The face-mesh and iris nets' sessions with their input buffers (landmarks.detect.mediapipe_mesh's predict_mesh and refine_eyes). */
export class FaceMesh {
  private readonly meshInput = new Float32Array(MESH_SIZE * MESH_SIZE * 3);

  constructor(readonly meshSession: ort.InferenceSession, readonly irisSession: ort.InferenceSession) {}

  /** The face-mesh net inside a region of the image (landmarks.detect.mediapipe_mesh.predict_mesh); eyes: then refine both eyes'
   * contours with the iris net and keep its irises (through `gate` where given). */
  async predictMesh(image: Tensor<Uint8Array>, region: Region, eyes = true, gate: IrisGate | null = null): Promise<MeshResult> {
    const matrix = regionToCrop(region, MESH_SIZE);
    warpAffineInto(image, matrix, MESH_SIZE, false, false, this.meshInput);
    const session = this.meshSession;
    const outputs = await session.run({ [session.inputNames[0]]: new ort.Tensor("float32", this.meshInput.slice(), [1, MESH_SIZE, MESH_SIZE, 3]) });
    const raw = outputBySize(outputs, session.outputNames, MESH_POINTS * 3);
    const flag = outputBySize(outputs, session.outputNames, 1);
    const inverse = invertAffine(matrix), depth = region.side / MESH_SIZE;
    let mesh: Float32Array = new Float32Array(MESH_POINTS * 3);
    for (let i = 0; i < MESH_POINTS; i++) {
      const [x, y] = toFrame(inverse, raw[3 * i], raw[3 * i + 1]);
      mesh[3 * i] = x; mesh[3 * i + 1] = y; mesh[3 * i + 2] = raw[3 * i + 2] * depth;
    }
    const presence = sigmoid(flag[0]);
    let irises: Float64Array | null = null;
    if (eyes) ({ mesh, irises } = await this.refineEyes(image, mesh, gate));
    return { mesh, presence, region, irises };
  }

  /** The iris net's input for one eye's square (landmarks.detect.mediapipe_mesh.eye_input): (64, 64, 3) float32 flat
   * in [0, 1] (mirrored for the image-right eye), a fresh array (the iris gate keeps it). */
  eyeInput(image: Tensor<Uint8Array>, region: Region, mirrored: boolean): Float32Array {
    const input = new Float32Array(IRIS_SIZE * IRIS_SIZE * 3);
    warpAffineInto(image, eyeCrop(region), IRIS_SIZE, true, mirrored, input);  // writes every value
    return input;
  }

  /** The iris net on one eye's input (landmarks.detect.mediapipe_mesh.iris_outputs); `input` stays the caller's (the
   * net gets a copy: onnxruntime's proxy worker takes over what it is given). */
  async irisOutputs(input: Float32Array): Promise<IrisOutputs> {
    const session = this.irisSession, copy = input.slice();
    const outputs = await session.run({ [session.inputNames[0]]: new ort.Tensor("float32", copy, [1, IRIS_SIZE, IRIS_SIZE, 3]) });
    return { eye: outputBySize(outputs, session.outputNames, 71 * 3), iris: outputBySize(outputs, session.outputNames, 5 * 3) };
  }

  /** The mesh (a copy) with both eyes' 16 contour vertices (x, y) from the iris net, and the irises it found
   * (landmarks.detect.mediapipe_mesh.refine_eyes; the two eyes run one after the other here). Unchanged when the mesh is not finite
   * or an eye's corners coincide. gate: an eye it keeps takes its last outputs instead of a run (IrisGate). */
  async refineEyes(image: Tensor<Uint8Array>, mesh: Float32Array, gate: IrisGate | null = null
                   ): Promise<{ mesh: Float32Array; irises: Float64Array }> {
    const refined = Float32Array.from(mesh);
    const irises = new Float64Array(8).fill(NaN);
    if (!refined.every(Number.isFinite)) {
      gate?.reset();
      return { mesh: refined, irises };
    }
    // both regions (and the mesh's own lid gaps) from the unrefined mesh, as the Python takes them before it writes
    // either eye
    const regions = EYE_CONTOURS.map(({ corners }) => eyeRegion(refined, corners));
    const gaps = gate === null ? [0, 0] : EYE_CONTOURS.map(({ contour }, eye) => {
      const m = eyeCrop(regions[eye]), own = new Float64Array(2 * contour.length);
      for (let k = 0; k < contour.length; k++) {  // loops, not closures made per frame (V8 optimised each again)
        const x = refined[3 * contour[k]], y = refined[3 * contour[k] + 1];
        own[2 * k] = m[0] * x + m[1] * y + m[2];
        own[2 * k + 1] = m[3] * x + m[4] * y + m[5];
      }
      return lidGap(own);
    });
    for (let eye = 0; eye < EYE_CONTOURS.length; eye++) {
      const { contour, mirrored } = EYE_CONTOURS[eye], region = regions[eye];
      if (!(region.side >= 1)) continue;
      const input = this.eyeInput(image, region, mirrored);
      let outputs = gate?.kept(eye, input, gaps[eye]) ?? null;
      if (outputs === null) {
        outputs = await this.irisOutputs(input);
        gate?.ran(eye, input, gaps[eye], outputs);
      }
      const { eye: points, iris } = outputs;
      const inverse = invertAffine(eyeCrop(region));
      for (let k = 0; k < contour.length; k++) {
        const [x, y] = toFrame(inverse, (mirrored ? IRIS_SIZE - points[3 * k] : points[3 * k]) - 0.5, points[3 * k + 1] - 0.5);
        refined[3 * contour[k]] = x; refined[3 * contour[k] + 1] = y;
      }
      irises.set(eyeIris(points, iris, inverse, mirrored), 4 * eye);
    }
    return { mesh: refined, irises };
  }
}

/** One eye's iris net outputs -> [x, y, radius, aperture] (landmarks.detect.mediapipe_mesh.eye_iris): the iris centre and radius in
 * frame pixels, the lid gap of the net's contour (the middle three pairs) over the eye's corner distance. inverse:
 * crop -> frame of the eye's crop. */
export function eyeIris(points: Float32Array, iris: Float32Array, inverse: Affine, mirrored: boolean): [number, number, number, number] {
  const frame: [number, number][] = [];
  for (let k = 0; k < 5; k++) {
    const x = mirrored ? IRIS_SIZE - iris[3 * k] : iris[3 * k];
    frame.push(toFrame(inverse, x - 0.5, iris[3 * k + 1] - 0.5));
  }
  let radius = 0;
  for (let k = 1; k < 5; k++) radius += Math.hypot(frame[k][0] - frame[0][0], frame[k][1] - frame[0][1]);
  return [frame[0][0], frame[0][1], radius / 4, (lidGap(points, 3) / IRIS_SIZE) * EYE_ROI_SCALE];
}
