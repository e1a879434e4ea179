// The default face tracker of the live path: landmarks/detect/mediapipe_tracker.py (MeshDetector, MeshTracker, _refined, mesh_box)
// on landmarks/detect/mediapipe_mesh.py's nets (facedetect.ts, facemesh.ts), and the iBUG-68 points from the mesh: landmarks/shape/mesh68.py
// (mesh_to_68, its jaw following the head's yaw) with landmarks/motion/mesh_rotation.py (mesh_head_pose: Kabsch against the
// canonical mesh over its rigid vertices) and landmarks/detect/dlib_tracker.py (pick_face, box_iou).
//
// Assets, paths relative to the Python's landmarks/assets folder (TRACKER_ASSET_FILES): the three MediaPipe ONNX
// graphs and the two fitted JSON records. In a browser: loadTrackerAssets((path) => fetch(base + path) as bytes),
// then createTracker(assets); per frame await tracker.update(frame) -> (68, 2) frame pixels or null.

import * as ort from "onnxruntime-web";

import { Detection, FaceDetector } from "./facedetect.js";
import { folderReader } from "./files.js";
import { FaceMesh, IrisGate, MESH_POINTS, MeshResult, regionFromDetection, regionFromMesh } from "./facemesh.js";
import { fusePRelu } from "./prelu.js";
import { Tensor, tensor } from "./tensor.js";

export const TRACKER_ASSET_FILES = {
  detector: "mediapipe/face_detection_short_range.onnx", // landmarks.detect.mediapipe_mesh.DETECTOR_FILE
  mesh: "mediapipe/face_landmark.onnx", // landmarks.detect.mediapipe_mesh.MESH_FILE
  iris: "mediapipe/iris_landmark.onnx", // landmarks.detect.mediapipe_mesh.IRIS_FILE
  mesh68: "mesh68.json", // landmarks.shape.mesh68.MAPPING_FILE
  canonical: "mesh_canonical.json", // landmarks.motion.mesh_rotation.CANONICAL_FILE
} as const;

/** landmarks/assets/mesh68.json: per iBUG point, [[vertex, weight], ...] at yaw 0 and per 30 degrees of yaw. */
export interface Mesh68Record { rows: [number, number][][]; yaw_rows: [number, number][][]; yaw_scale_degrees?: number }
/** landmarks/assets/mesh_canonical.json: (468, 3) vertices and (468,) 0/1 rigid flags. */
export interface CanonicalRecord { vertices: number[][]; rigid: (number | boolean)[] }

export interface TrackerAssets {
  detector: Uint8Array; mesh: Uint8Array; iris: Uint8Array; mesh68: Mesh68Record; canonical: CanonicalRecord;
}

export const NUM_LANDMARKS = 68;
export const YAW_SCALE = 30; // landmarks.shape.mesh68.YAW_SCALE
export const MAX_YAW = 45; // landmarks.shape.mesh68.MAX_YAW

/** The 68-from-468 mapping, sparse (CSR) rows, and the canonical mesh's rigid vertices for the yaw. */
export interface Mesh68Mapping {
  start: Int32Array; vertex: Int32Array; weight: Float32Array;
  yawStart: Int32Array; yawVertex: Int32Array; yawWeight: Float32Array;
  rigid: Int32Array; canonical: Float64Array; // (R,) vertex indices, (R, 3) their canonical positions, centred
}

function sparse(rows: [number, number][][]): { start: Int32Array; vertex: Int32Array; weight: Float32Array } {
  if (rows.length !== NUM_LANDMARKS) throw new Error(`mesh68 mapping must have ${NUM_LANDMARKS} rows, got ${rows.length}`);
  const start = new Int32Array(rows.length + 1);
  rows.forEach((row, i) => { start[i + 1] = start[i] + row.length; });
  const vertex = new Int32Array(start[rows.length]), weight = new Float32Array(start[rows.length]);
  let k = 0;
  for (const row of rows) for (const [v, w] of row) { vertex[k] = v; weight[k++] = w; }
  return { start, vertex, weight };
}

/** The mapping of landmarks.shape.mesh68 (mapping, yaw_mapping) and the canonical record of landmarks.motion.mesh_rotation. */
export function mesh68Mapping(mesh68: Mesh68Record, canonical: CanonicalRecord): Mesh68Mapping {
  const rows = sparse(mesh68.rows), yaw = sparse(mesh68.yaw_rows);
  const rigid = Int32Array.from(canonical.rigid.flatMap((flag, i) => (flag ? [i] : [])));
  const positions = new Float64Array(rigid.length * 3);
  const mean = [0, 0, 0];
  rigid.forEach((v, i) => { for (let c = 0; c < 3; c++) { positions[3 * i + c] = canonical.vertices[v][c]; mean[c] += canonical.vertices[v][c] / rigid.length; } });
  for (let i = 0; i < rigid.length; i++) for (let c = 0; c < 3; c++) positions[3 * i + c] -= mean[c];
  return { ...rows, yawStart: yaw.start, yawVertex: yaw.vertex, yawWeight: yaw.weight, rigid, canonical: positions };
}

/** Largest eigenvector of a symmetric 4x4 matrix (cyclic Jacobi). */
function topEigenvector(a: Float64Array): Float64Array {
  const v = new Float64Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
  for (let sweep = 0; sweep < 30; sweep++) {
    let off = 0;
    for (let p = 0; p < 4; p++) for (let q = p + 1; q < 4; q++) off += a[4 * p + q] ** 2;
    if (off < 1e-30) break;
    for (let p = 0; p < 4; p++) for (let q = p + 1; q < 4; q++) {
      const apq = a[4 * p + q];
      if (Math.abs(apq) < 1e-300) continue;
      const theta = (a[4 * q + q] - a[4 * p + p]) / (2 * apq);
      const t = Math.sign(theta || 1) / (Math.abs(theta) + Math.sqrt(theta * theta + 1));
      const c = 1 / Math.sqrt(t * t + 1), s = t * c;
      for (let k = 0; k < 4; k++) { // columns p, q
        const akp = a[4 * k + p], akq = a[4 * k + q];
        a[4 * k + p] = c * akp - s * akq; a[4 * k + q] = s * akp + c * akq;
      }
      for (let k = 0; k < 4; k++) { // rows p, q
        const apk = a[4 * p + k], aqk = a[4 * q + k];
        a[4 * p + k] = c * apk - s * aqk; a[4 * q + k] = s * apk + c * aqk;
      }
      for (let k = 0; k < 4; k++) {
        const vkp = v[4 * k + p], vkq = v[4 * k + q];
        v[4 * k + p] = c * vkp - s * vkq; v[4 * k + q] = s * vkp + c * vkq;
      }
    }
  }
  let best = 0;
  for (let i = 1; i < 4; i++) if (a[5 * i] > a[5 * best]) best = i;
  return Float64Array.from([0, 1, 2, 3], (k) => v[4 * k + best]);
}

/** The head's yaw in degrees from a (468, 3) flat mesh (landmarks.motion.mesh_rotation.mesh_head_pose's yaw): the rotation of
 * the canonical mesh onto it over the rigid vertices (Kabsch, here in Horn's quaternion form: the same optimal
 * proper rotation), then landmarks.motion.head_pose.angles_from_rotation. NaN when the mesh is not finite. */
export function meshHeadYaw(mesh: Float32Array | Float64Array, mapping: Mesh68Mapping): number {
  const { rigid, canonical } = mapping, n = rigid.length;
  const mean = [0, 0, 0];
  for (const v of rigid) for (let c = 0; c < 3; c++) mean[c] += mesh[3 * v + c] / n;
  if (!mean.every(Number.isFinite)) return NaN;
  const s = new Float64Array(9); // s[3a + b] = sum canonical_a * mesh_b
  for (let i = 0; i < n; i++) {
    const v = rigid[i];
    for (let a = 0; a < 3; a++) for (let b = 0; b < 3; b++) s[3 * a + b] += canonical[3 * i + a] * (mesh[3 * v + b] - mean[b]);
  }
  const [xx, xy, xz, yx, yy, yz, zx, zy, zz] = s;
  const q = topEigenvector(new Float64Array([
    xx + yy + zz, yz - zy, zx - xz, xy - yx,
    yz - zy, xx - yy - zz, xy + yx, zx + xz,
    zx - xz, xy + yx, -xx + yy - zz, yz + zy,
    xy - yx, zx + xz, yz + zy, -xx - yy + zz,
  ]));
  const [w, x, y, z] = q;
  const r20 = 2 * (x * z - w * y), r22 = w * w - x * x - y * y + z * z;
  return (-Math.atan2(-r20, r22) * 180) / Math.PI;
}

/** (468, 3) mesh -> (68, 2) iBUG points (landmarks.shape.mesh68.mesh_to_68): the mapping's rows, plus the jaw's yaw rows
 * times clip(yaw, +-45) / 30. */
export function meshTo68(mesh: Tensor, mapping: Mesh68Mapping): Tensor<Float64Array> {
  if (mesh.data.length !== MESH_POINTS * 3) throw new Error(`mesh must be (468, 3), got [${mesh.shape}]`);
  const data = mesh.data as Float32Array | Float64Array;
  const turn = Math.min(MAX_YAW, Math.max(-MAX_YAW, meshHeadYaw(data, mapping))) / YAW_SCALE;
  const out = new Float64Array(NUM_LANDMARKS * 2);
  for (let p = 0; p < NUM_LANDMARKS; p++) {
    let x = 0, y = 0, yawX = 0, yawY = 0;
    for (let k = mapping.start[p]; k < mapping.start[p + 1]; k++) {
      const v = mapping.vertex[k], w = mapping.weight[k];
      x += w * data[3 * v]; y += w * data[3 * v + 1];
    }
    for (let k = mapping.yawStart[p]; k < mapping.yawStart[p + 1]; k++) {
      const v = mapping.yawVertex[k], w = mapping.yawWeight[k];
      yawX += w * data[3 * v]; yawY += w * data[3 * v + 1];
    }
    // (the yaw rows are zero off the jaw: 0 * NaN would still be NaN there, as in the Python)
    out[2 * p] = x + turn * yawX; out[2 * p + 1] = y + turn * yawY;
  }
  return tensor(out, [NUM_LANDMARKS, 2]);
}

/** meshTo68 from the two JSON records (for the bridge: the records travel as plain objects). */
export function meshTo68Records(mesh: Tensor, mesh68: Mesh68Record, canonical: CanonicalRecord): Tensor<Float64Array> {
  return meshTo68(mesh, mesh68Mapping(mesh68, canonical));
}

/** x0, y0, x1, y1 of a (468, 3) flat mesh's x, y (landmarks.detect.mediapipe_tracker.mesh_box). */
export function meshBox(mesh: Float32Array): [number, number, number, number] {
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  for (let i = 0; i < MESH_POINTS; i++) {
    const x = mesh[3 * i], y = mesh[3 * i + 1];
    if (x < x0) x0 = x; if (x > x1) x1 = x; if (y < y0) y0 = y; if (y > y1) y1 = y;
  }
  return [x0, y0, x1, y1];
}

function boxArea(box: number[]): number {
  return Math.max(box[2] - box[0], 0) * Math.max(box[3] - box[1], 0);
}

/** Intersection over union of two boxes (landmarks.detect.dlib_tracker.box_iou). */
export function boxIou(a: number[], b: number[]): number {
  const inter = Math.max(0, Math.min(a[2], b[2]) - Math.max(a[0], b[0])) * Math.max(0, Math.min(a[3], b[3]) - Math.max(a[1], b[1]));
  const union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter;
  return union > 0 ? inter / union : 0;
}

/** Which face (boxes largest first) to track (landmarks.detect.dlib_tracker.pick_face): after a loss the one overlapping the last
 * tracked box (IoU > 0.3), else the faceIndex-th; null when there are too few. */
export function pickFace(boxes: number[][], lastBox: number[] | null, faceIndex: number): number | null {
  if (lastBox !== null && boxes.length > 0) {
    const overlaps = boxes.map((box) => boxIou(box, lastBox));
    const best = overlaps.indexOf(Math.max(...overlaps));
    if (overlaps[best] > 0.3) return best;
  }
  return faceIndex < boxes.length ? faceIndex : null;
}

export interface TrackerOptions {
  minScore?: number; // detection probability threshold (0.5)
  minPresence?: number; // the mesh net's face probability below which a mesh is dropped (0.5)
  faceIndex?: number; // which face, largest first (0)
  maxScaleChange?: number; // 0.3
  maxShift?: number; // 0.4
  irisGate?: boolean; // rerun the iris net on an eye only where it changed (facemesh.ts IrisGate): live tracking
}

/** One face's mesh and 68 points through frames (landmarks.detect.mediapipe_tracker.MeshTracker with its MeshDetector): the mesh
 * net in the region of the previous frame's mesh; a full detection (then two mesh passes) on the first frame, and
 * whenever the face's presence drops or it jumps. */
export class MeshTracker {
  mesh: Float32Array | null = null; // the last frame's (468, 3) flat mesh, null when missing
  irises: Float64Array | null = null; // the last frame's (2, 4) flat [x, y, radius, aperture] rows
  lastBox: number[] | null = null; // kept across losses: prefer the same face afterwards
  detections = 0;
  readonly minPresence: number; readonly faceIndex: number; readonly maxScaleChange: number; readonly maxShift: number;
  readonly gate: IrisGate | null;  // options.irisGate: the iris net only where an eye changed

  constructor(readonly detector: FaceDetector, readonly faceMesh: FaceMesh, readonly mapping: Mesh68Mapping,
              options: TrackerOptions = {}) {
    this.minPresence = options.minPresence ?? 0.5;
    this.faceIndex = options.faceIndex ?? 0;
    this.maxScaleChange = options.maxScaleChange ?? 0.3;
    this.maxShift = options.maxShift ?? 0.4;
    this.gate = options.irisGate ? new IrisGate() : null;
  }

  /** Forget the face: the next frame starts with a full detection. */
  reset(): void {
    this.mesh = null; this.irises = null; this.lastBox = null; this.detections = 0;
    this.gate?.reset();
  }

  /** Mesh from a detection's region, then once more from the mesh's own region (landmarks.detect.mediapipe_tracker._refined). */
  async refined(image: Tensor<Uint8Array>, detection: Detection): Promise<MeshResult> {
    const first = await this.faceMesh.predictMesh(image, regionFromDetection(detection));
    const second = await this.faceMesh.predictMesh(image, regionFromMesh(first.mesh));
    return second.presence >= first.presence * 0.5 ? second : first;
  }

  /** Every face's detection and mesh, largest first (landmarks.detect.mediapipe_tracker.MeshDetector.meshes). */
  async meshes(image: Tensor<Uint8Array>): Promise<MeshResult[]> {
    const found: MeshResult[] = [];
    for (const detection of await this.detector.detectTiled(image)) {
      const result = await this.refined(image, detection);
      if (result.presence >= this.minPresence) found.push(result);
    }
    return found.map((r) => ({ r, area: boxArea(meshBox(r.mesh)) })).sort((a, b) => b.area - a.area).map(({ r }) => r);
  }

  private plausible(mesh: Float32Array, previous: Float32Array): boolean {
    if (!mesh.every(Number.isFinite)) return false;
    const box = meshBox(mesh), old = meshBox(previous);
    const size = Math.sqrt((box[2] - box[0]) * (box[3] - box[1])), oldSize = Math.sqrt((old[2] - old[0]) * (old[3] - old[1]));
    const ratio = size / Math.max(oldSize, 1e-6);
    if (!(1 / (1 + this.maxScaleChange) <= ratio && ratio <= 1 + this.maxScaleChange)) return false;
    const shift = Math.hypot((box[0] + box[2]) / 2 - (old[0] + old[2]) / 2, (box[1] + box[3]) / 2 - (old[1] + old[3]) / 2);
    return shift <= this.maxShift * oldSize;
  }

  private async detect(frame: Tensor<Uint8Array>): Promise<MeshResult | null> {
    this.detections += 1;
    const found = await this.meshes(frame);
    if (found.length === 0) return null;
    const choice = pickFace(found.map((r) => meshBox(r.mesh)), this.lastBox, this.faceIndex);
    return choice === null ? null : found[choice];
  }

  /** Track one frame (landmarks.detect.mediapipe_tracker.MeshTracker.update). frame: (H, W, 3) uint8 RGB. Returns (68, 2) frame
   * pixels, or null (no face: detection runs again on the next frame). */
  async update(frame: Tensor<Uint8Array>): Promise<Tensor<Float64Array> | null> {
    if (frame.shape.length !== 3 || frame.shape[2] !== 3 || !(frame.data instanceof Uint8Array)) {
      throw new Error(`frame must be (H, W, 3) uint8 RGB, got [${frame.shape}]`);
    }
    let kept: MeshResult | null = null;
    if (this.mesh !== null) {
      const result = await this.faceMesh.predictMesh(frame, regionFromMesh(this.mesh), true, this.gate);
      if (result.presence >= this.minPresence && this.plausible(result.mesh, this.mesh)) kept = result;
    }
    if (kept === null) {
      this.gate?.reset();
      kept = await this.detect(frame);
    }
    this.mesh = kept === null ? null : kept.mesh;
    this.irises = kept === null ? null : kept.irises;
    if (this.mesh === null) return null;
    this.lastBox = meshBox(this.mesh);
    return meshTo68(tensor(this.mesh, [MESH_POINTS, 3]), this.mapping);
  }
}

function inNode(): boolean {
  return typeof process !== "undefined" && typeof process.versions?.node === "string";
}

/** The tracker from its assets' bytes and records (in Node, onnxruntime-web runs single-threaded). */
export async function createTracker(assets: TrackerAssets, options: TrackerOptions = {}): Promise<MeshTracker> {
  if (inNode()) ort.env.wasm.numThreads = 1;
  // the nets' five-node PReLUs as PRelu nodes: the same outputs, a third less time in WASM (src/prelu.ts)
  const create = (bytes: Uint8Array) => ort.InferenceSession.create(fusePRelu(bytes), { executionProviders: ["wasm"], graphOptimizationLevel: "all" });
  const [detector, mesh, iris] = await Promise.all([create(assets.detector), create(assets.mesh), create(assets.iris)]);
  return new MeshTracker(new FaceDetector(detector, options.minScore ?? 0.5), new FaceMesh(mesh, iris),
                         mesh68Mapping(assets.mesh68, assets.canonical), options);
}

/** The tracker's assets through a reader of TRACKER_ASSET_FILES' paths (a browser: fetch(base + path) as bytes). */
export async function loadTrackerAssets(read: (path: string) => Promise<Uint8Array>): Promise<TrackerAssets> {
  const f = TRACKER_ASSET_FILES;
  const [detector, mesh, iris, mesh68, canonical] = await Promise.all([f.detector, f.mesh, f.iris, f.mesh68, f.canonical].map(read));
  const json = (bytes: Uint8Array) => JSON.parse(new TextDecoder().decode(bytes));
  return { detector, mesh, iris, mesh68: json(mesh68), canonical: json(canonical) };
}

/** Node only: the assets from a folder laid out as landmarks/assets (node:fs imported at run time, so that browser
 * bundles never pull it in). */
export async function readTrackerAssets(folder: string): Promise<TrackerAssets> {
  return loadTrackerAssets(await folderReader(folder));
}

/** What trackFramesDetailed gives: (T, 68, 2) points, (T, 468, 3) meshes, (T, 2, 4) irises (NaN where no face), the
 * full detections run, each frame's update time in ms, and with the iris gate its runs and skips of the iris net. */
export interface TrackRun {
  landmarks: Tensor<Float64Array>; meshes: Tensor<Float32Array>; irises: Tensor<Float64Array>; detections: number; ms: Float64Array;
  irisRuns: number; irisSkips: number;
}

/** Node: track (T, H, W, 3) uint8 frames from a fresh start (landmarks.detect.dlib_tracker.FrameTracker.track_frames) with the
 * assets of a landmarks/assets folder. */
export async function trackFramesDetailed(assetsFolder: string, frames: Tensor<Uint8Array>, options: TrackerOptions = {}): Promise<TrackRun> {
  const [count, height, width] = frames.shape;
  const tracker = await createTracker(await readTrackerAssets(assetsFolder), options);
  const size = height * width * 3;
  const landmarks = new Float64Array(count * NUM_LANDMARKS * 2).fill(NaN);
  const meshes = new Float32Array(count * MESH_POINTS * 3).fill(NaN);
  const irises = new Float64Array(count * 8).fill(NaN);
  const ms = new Float64Array(count);
  for (let t = 0; t < count; t++) {
    const frame = tensor(frames.data.subarray(t * size, (t + 1) * size), [height, width, 3]);
    const start = performance.now();
    const points = await tracker.update(frame);
    ms[t] = performance.now() - start;
    if (points === null) continue;
    landmarks.set(points.data, t * NUM_LANDMARKS * 2);
    meshes.set(tracker.mesh!, t * MESH_POINTS * 3);
    if (tracker.irises) irises.set(tracker.irises, t * 8);
  }
  return {
    landmarks: tensor(landmarks, [count, NUM_LANDMARKS, 2]), meshes: tensor(meshes, [count, MESH_POINTS, 3]),
    irises: tensor(irises, [count, 2, 4]), detections: tracker.detections, ms,
    irisRuns: tracker.gate?.runs ?? 0, irisSkips: tracker.gate?.skips ?? 0,
  };
}

/** Node: (T, H, W, 3) uint8 frames -> (T, 68, 2) frame-pixel points, NaN where no face. */
export async function trackFrames(assetsFolder: string, frames: Tensor<Uint8Array>): Promise<Tensor<Float64Array>> {
  return (await trackFramesDetailed(assetsFolder, frames)).landmarks;
}
