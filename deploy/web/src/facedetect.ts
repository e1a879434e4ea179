// MediaPipe's short-range face detector (BlazeFace) around its ONNX graph: landmarks/detect/mediapipe_mesh.py (ssd_anchors,
// _letterbox, detector_input, decode_detections, weighted_nms, detect_faces, detect_tiled). Same constants, same
// conventions: boxes x0, y0, x1, y1 and keypoints (6, 2) in frame pixels (float32 values, as the Python keeps them).

import * as ort from "onnxruntime-web";
import { Tensor } from "./tensor.js";

export const DETECTOR_SIZE = 128;
export const NMS_THRESHOLD = 0.3;
export const TILE_LEVELS = 2; // tiles of 1/2, then 1/4 of the shorter side
export const MIN_TILE = 160; // px: below this a tile adds nothing the whole frame did not see

/** One detection in frame pixels (landmarks.detect.mediapipe_mesh.Detection). box: x0, y0, x1, y1; keypoints: (6, 2) flat, x, y of
 * the image-left eye, image-right eye, nose tip, mouth centre, image-left ear, image-right ear. */
export interface Detection {
  box: Float32Array;
  keypoints: Float32Array;
  score: number;
}

/** A rectangle of a frame: the detector sees only it (a tile), its pixels offset by (left, top). */
interface View { image: Tensor<Uint8Array>; left: number; top: number; width: number; height: number }

let anchorCache: Float32Array | null = null;

/** (896, 2) flat anchor centres in [0, 1] (landmarks.detect.mediapipe_mesh.ssd_anchors): strides 8 (2 per cell) and 16 (6). */
export function ssdAnchors(): Float32Array {
  if (anchorCache) return anchorCache;
  const out = new Float32Array(896 * 2);
  let k = 0;
  for (const [stride, perCell] of [[8, 2], [16, 6]]) {
    const cells = DETECTOR_SIZE / stride;
    for (let y = 0; y < cells; y++) for (let x = 0; x < cells; x++) {
      for (let a = 0; a < perCell; a++) { out[k++] = (x + 0.5) / cells; out[k++] = (y + 0.5) / cells; }
    }
  }
  return (anchorCache = out);
}

/** OpenCV's INTER_AREA source weights of one axis (computeResizeAreaTab): per output pixel, [start, weights...]. */
function areaTable(source: number, target: number): { start: Int32Array; count: Int32Array; weight: Float32Array; width: number } {
  const scale = 1 / (target / source);
  const width = Math.ceil(scale) + 2;
  const start = new Int32Array(target), count = new Int32Array(target), weight = new Float32Array(target * width);
  for (let d = 0; d < target; d++) {
    const f1 = d * scale, f2 = f1 + scale, cell = Math.min(scale, source - f1);
    const s2 = Math.min(Math.floor(f2), source - 1);
    const s1 = Math.min(Math.ceil(f1), s2);
    let n = 0, first = s1;
    const put = (sx: number, w: number) => { if (n === 0) first = sx; weight[d * width + n++] = w; };
    if (s1 - f1 > 1e-3) put(s1 - 1, (s1 - f1) / cell);
    for (let s = s1; s < s2; s++) put(s, 1 / cell);
    if (f2 - s2 > 1e-3) put(s2, Math.min(Math.min(f2 - s2, 1), cell) / cell);
    start[d] = first; count[d] = n;
  }
  return { start, count, weight, width };
}

/** OpenCV's INTER_LINEAR source weights of one axis (half-pixel centres, edges clamped). */
function linearTable(source: number, target: number): { start: Int32Array; count: Int32Array; weight: Float32Array; width: number } {
  const scale = source / target;
  const start = new Int32Array(target), count = new Int32Array(target), weight = new Float32Array(target * 2);
  for (let d = 0; d < target; d++) {
    const f = (d + 0.5) * scale - 0.5;
    let x0 = Math.floor(f), t = f - x0;
    if (x0 < 0) { x0 = 0; t = 0; }
    if (x0 >= source - 1) { x0 = source - 1; t = 0; }
    start[d] = x0;
    if (t === 0) { count[d] = 1; weight[2 * d] = 1; } else { count[d] = 2; weight[2 * d] = 1 - t; weight[2 * d + 1] = t; }
  }
  return { start, count, weight, width: 2 };
}

/** The view letterboxed into size x size, scaled to [-1, 1] into out (landmarks.detect.mediapipe_mesh.detector_input and _letterbox:
 * INTER_AREA when shrinking, INTER_LINEAR when enlarging, black bars). Returns scale and offset: frame = (input -
 * offset) / scale. */
function letterbox(view: View, size: number, out: Float32Array): { scale: number; offset: [number, number] } {
  const { image, width, height } = view;
  const rowStride = image.shape[1] * 3;
  const scale = size / Math.max(height, width);
  const newW = Math.max(1, Math.round(width * scale)), newH = Math.max(1, Math.round(height * scale));
  const table = scale < 1 ? areaTable : linearTable;
  const tx = table(width, newW), ty = table(height, newH);
  const left = Math.floor((size - newW) / 2), top = Math.floor((size - newH) / 2);
  out.fill(-1);
  const data = image.data;
  const row = new Float32Array(width * 3);
  for (let y = 0; y < newH; y++) {
    // vertical pass into one source-width row, then the horizontal taps
    row.fill(0);
    for (let j = 0; j < ty.count[y]; j++) {
      const w = ty.weight[y * ty.width + j];
      if (w === 0) continue;
      const base = (view.top + ty.start[y] + j) * rowStride + view.left * 3;
      for (let i = 0; i < width * 3; i++) row[i] += w * data[base + i];
    }
    let o = ((top + y) * size + left) * 3;
    for (let x = 0; x < newW; x++, o += 3) {
      let r = 0, g = 0, b = 0;
      for (let i = 0; i < tx.count[x]; i++) {
        const w = tx.weight[x * tx.width + i], s = (tx.start[x] + i) * 3;
        r += w * row[s]; g += w * row[s + 1]; b += w * row[s + 2];
      }
      // uint8 as OpenCV leaves it, then the net's scaling
      out[o] = clampByte(r) / 127.5 - 1; out[o + 1] = clampByte(g) / 127.5 - 1; out[o + 2] = clampByte(b) / 127.5 - 1;
    }
  }
  return { scale, offset: [left, top] };
}

function clampByte(v: number): number {
  const r = Math.round(v);
  return r < 0 ? 0 : r > 255 ? 255 : r;
}

/** The nets' logits -> probabilities, logits clipped at +-100 (landmarks.detect.mediapipe_mesh.sigmoid). */
export function sigmoid(logit: number): number {
  return 1 / (1 + Math.exp(-Math.min(100, Math.max(-100, logit))));
}

function iou(boxes: Float32Array, a: number, b: number): number {
  const x0 = Math.max(boxes[4 * a], boxes[4 * b]), y0 = Math.max(boxes[4 * a + 1], boxes[4 * b + 1]);
  const x1 = Math.min(boxes[4 * a + 2], boxes[4 * b + 2]), y1 = Math.min(boxes[4 * a + 3], boxes[4 * b + 3]);
  const inter = Math.max(x1 - x0, 0) * Math.max(y1 - y0, 0);
  const areaA = (boxes[4 * a + 2] - boxes[4 * a]) * (boxes[4 * a + 3] - boxes[4 * a + 1]);
  const areaB = (boxes[4 * b + 2] - boxes[4 * b]) * (boxes[4 * b + 3] - boxes[4 * b + 1]);
  return inter / Math.max(areaA + areaB - inter, 1e-9);
}

/** MediaPipe's WEIGHTED suppression (landmarks.detect.mediapipe_mesh.weighted_nms): each cluster (IoU > threshold with its best box)
 * becomes the score-weighted mean of its boxes and keypoints, with the best score. boxes (n, 4), keypoints (n, 6, 2)
 * flat. (The best box always joins its own cluster, so a zero-area box cannot stall the loop.) */
export function weightedNms(boxes: Float32Array, keypoints: Float32Array, scores: ArrayLike<number>,
                            threshold = NMS_THRESHOLD): Detection[] {
  const n = scores.length;
  let remaining = Array.from({ length: n }, (_, i) => i).sort((a, b) => scores[b] - scores[a]);
  const kept: Detection[] = [];
  while (remaining.length > 0) {
    const best = remaining[0];
    const cluster = remaining.filter((i) => i === best || iou(boxes, best, i) > threshold);
    const box = new Float64Array(4), points = new Float64Array(12);
    let total = 0;
    for (const i of cluster) {
      const w = scores[i];
      total += w;
      for (let k = 0; k < 4; k++) box[k] += w * boxes[4 * i + k];
      for (let k = 0; k < 12; k++) points[k] += w * keypoints[12 * i + k];
    }
    kept.push({ box: Float32Array.from(box, (v) => v / total), keypoints: Float32Array.from(points, (v) => v / total),
                score: scores[best] });
    const gone = new Set(cluster);
    remaining = remaining.filter((i) => !gone.has(i));
  }
  return kept;
}

/** The detector's outputs -> detections in frame pixels, best first (landmarks.detect.mediapipe_mesh.decode_detections).
 * regressors: (896 * 16) flat; logits: (896) flat. */
export function decodeDetections(regressors: Float32Array, logits: Float32Array, scale: number, offset: [number, number],
                                 minScore = 0.5): Detection[] {
  const anchors = ssdAnchors();
  const keep: number[] = [], scores: number[] = [];
  for (let i = 0; i < 896; i++) {
    const score = sigmoid(logits[i]);
    if (score >= minScore) { keep.push(i); scores.push(score); }
  }
  if (keep.length === 0) return [];
  const boxes = new Float32Array(keep.length * 4), points = new Float32Array(keep.length * 12);
  keep.forEach((a, n) => {
    const ax = Math.fround(anchors[2 * a] * DETECTOR_SIZE), ay = Math.fround(anchors[2 * a + 1] * DETECTOR_SIZE);
    const raw = a * 16;
    const cx = Math.fround(ax + regressors[raw]), cy = Math.fround(ay + regressors[raw + 1]);
    const hw = Math.fround(regressors[raw + 2] / 2), hh = Math.fround(regressors[raw + 3] / 2);
    boxes.set([cx - hw, cy - hh, cx + hw, cy + hh], 4 * n);
    for (let k = 0; k < 6; k++) {
      points[12 * n + 2 * k] = ax + regressors[raw + 4 + 2 * k];
      points[12 * n + 2 * k + 1] = ay + regressors[raw + 5 + 2 * k];
    }
  });
  return weightedNms(boxes, points, scores).map((d) => ({
    box: Float32Array.from(d.box, (v, i) => (v - offset[i % 2]) / scale),
    keypoints: Float32Array.from(d.keypoints, (v, i) => (v - offset[i % 2]) / scale),
    score: d.score,
  }));
}

/** The short-range detector's session and its input buffer. */
export class FaceDetector {
  private readonly input = new Float32Array(DETECTOR_SIZE * DETECTOR_SIZE * 3);

  constructor(readonly session: ort.InferenceSession, readonly minScore = 0.5) {}

  /** BlazeFace on a rectangle of the frame (landmarks.detect.mediapipe_mesh.detect_faces; the whole frame when left, top, width,
   * height are omitted): detections in frame pixels, best first. */
  async detectFaces(image: Tensor<Uint8Array>, left = 0, top = 0, width = image.shape[1], height = image.shape[0]):
      Promise<Detection[]> {
    const { scale, offset } = letterbox({ image, left, top, width, height }, DETECTOR_SIZE, this.input);
    const feeds = { [this.session.inputNames[0]]: new ort.Tensor("float32", this.input.slice(), [1, DETECTOR_SIZE, DETECTOR_SIZE, 3]) };
    const outputs = await this.session.run(feeds);
    let regressors: Float32Array | null = null, logits: Float32Array | null = null;
    for (const name of this.session.outputNames) {
      const data = outputs[name].data as Float32Array;
      if (data.length === 896 * 16) regressors = data; else if (data.length === 896) logits = data;
    }
    if (!regressors || !logits) throw new Error("the face detector's outputs are not (896, 16) and (896, 1)");
    const found = decodeDetections(regressors, logits, scale, offset, this.minScore);
    for (const d of found) {
      for (let k = 0; k < 4; k++) d.box[k] += k % 2 === 0 ? left : top;
      for (let k = 0; k < 12; k++) d.keypoints[k] += k % 2 === 0 ? left : top;
    }
    return found;
  }

  /** Whole-frame detection, then, when nothing is found, overlapping square tiles of half, then a quarter of the
   * shorter side (landmarks.detect.mediapipe_mesh.detect_tiled). Detections in frame pixels, best first. */
  async detectTiled(image: Tensor<Uint8Array>): Promise<Detection[]> {
    const found = await this.detectFaces(image);
    if (found.length > 0) return found;
    const [height, width] = image.shape;
    const candidates: Detection[] = [];
    let side = Math.min(height, width);
    for (let level = 0; level < TILE_LEVELS; level++) {
      side = Math.floor(side / 2);
      if (side < MIN_TILE || candidates.length > 0) break;
      for (const [top, left] of tiles(height, width, side)) {
        candidates.push(...(await this.detectFaces(image, left, top, side, side)));
      }
    }
    if (candidates.length === 0) return [];
    const boxes = new Float32Array(candidates.length * 4), points = new Float32Array(candidates.length * 12);
    candidates.forEach((d, i) => { boxes.set(d.box, 4 * i); points.set(d.keypoints, 12 * i); });
    return weightedNms(boxes, points, Float32Array.from(candidates, (d) => d.score));
  }
}

/** Top-left corners [top, left] of side x side tiles overlapping by half, covering the frame (landmarks.detect.mediapipe_mesh._tiles). */
function tiles(height: number, width: number, side: number): [number, number][] {
  const step = Math.max(1, Math.floor(side / 2));
  const starts = (extent: number) => {
    const set = new Set<number>();
    for (let v = 0; v < Math.max(1, extent - side); v += step) set.add(v);
    set.add(Math.max(0, extent - side));
    return [...set].sort((a, b) => a - b);
  };
  const out: [number, number][] = [];
  for (const top of starts(height)) for (const left of starts(width)) out.push([top, left]);
  return out;
}
