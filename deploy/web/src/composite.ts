// Composite a re-enacted face into a scene frame: landmarks/scene/compositing.py (composite_face, with its SceneLayers path
// _keep_background, the head layer's rigid + TPS field made on a grid, _inside_heads, _within_head, the face
// layer's feathered hull alpha and the colour match with blur), with cv2.GaussianBlur (float32, reflect-101) from
// remap.ts and the masks (cv2.ellipse, cv2.fillConvexPoly, cv2.convexHull, cv2.distanceTransform) from shapes.ts,
// each giving OpenCV's pixels. Outside the head box the frame is the scene's, bit for bit.

import { cropTransform, faceGeometry, invertAffine, similarityAffine, similarityProcrustes,
         transformPoints } from "./geometry.js";
import { PixelImage, bilinearAt, clampedView, densifyGrid, gaussianBlurF32, remapCubic, resizeArea, resizeLinear,
         roundHalfEven as rint, warpAffineCubic } from "./remap.js";
import { CubicSources } from "./remap_wasm.js";
import { RIGID_INDEX } from "./retarget.js";
import { convexHull, distanceTransform, fillConvexPoly, fillEllipse } from "./shapes.js";
import { Affine, Tensor, checkPoints, tensor } from "./tensor.js";
import { foldedFraction, tpsGridMap } from "./tps.js";

// landmarks/scene/compositing.py
const HEAD_CENTRE_UP = 0.08;
const HEAD_SEMI_AXES = [0.36, 0.46];
const HEAD_INNER = 0.7;
const FOREHEAD_LIFT = 0.3;
const FACE_MARGIN = 0.02;
const FACE_FEATHER = 0.05;
const COLOUR_BAND = 0.06;
const COLOUR_SIGMA = 0.12;
const COLOUR_LIMIT = 40.0;
const STILL = 0.25;
const HEAD_WARP_INDEX = [...Array.from({ length: 36 }, (_, i) => i), 36, 39, 42, 45];
const HEAD_GRID_CELLS = 48;
const MOVING = 1.0;
const PERSON_SCALE = 1.6;
const PERSON_INNER = 0.8;
const NECK_FADE = 0.3;
const INNER_RETRIES = [0.0, 0.15, 0.3];
const EDGE_RAMP = 4.0;
const EDGE_REACH = 0.5;
const EDGE_CELLS = 3;
const f32 = Math.fround;

/** The scene split into what moves with the head and what stays (landmarks.scene.compositing.SceneLayers, made in Python by
 * background_plate). matte: (H, W) float32 in [0, 1]; plate: (H, W, 3) uint8. */
export interface SceneLayers { matte: Tensor<Float32Array>; plate: Tensor<Uint8Array> }

/** What compositeFace made (landmarks.scene.compositing.Composite). */
export interface Composite {
  frame: Tensor<Uint8Array>;  // (H, W, 3): the scene with the re-enacted head
  box: Box | null;  // (x0, y0, x1, y1): the only region that differs from the scene
  faceAlpha: Tensor<Float32Array> | null;  // (y1 - y0, x1 - x0): the face layer's weight
  headMotion: Affine | null;  // the head's rigid part, the similarity scene -> target on RIGID_INDEX
}

interface Ellipse { cx: number; cy: number; ax: number; ay: number }
/** (x0, y0, x1, y1) frame pixels. */
export type Box = [number, number, number, number];

/** The face's crop side in frame pixels (landmarks.scene.compositing.face_side). */
export function faceSide(landmarks: Tensor): number {
  const m = cropTransform(landmarks, 1024);
  return 1024 / Math.sqrt(Math.abs(m[0] * m[4] - m[1] * m[3]));
}

function headEllipse(points: Tensor): Ellipse {
  const side = faceSide(points), [left, right, mouth] = faceGeometry(points);
  const cx = ((left[0] + right[0]) / 2 + mouth[0]) / 2, cy = ((left[1] + right[1]) / 2 + mouth[1]) / 2;
  return { cx, cy: cy - HEAD_CENTRE_UP * side, ax: HEAD_SEMI_AXES[0] * side, ay: HEAD_SEMI_AXES[1] * side };
}

/** A head ellipse's radius at frame pixel (x, y), float32 as numpy has it (landmarks.scene.compositing._radius_at). */
function radiusAt(e: Ellipse, x: number, y: number): number {
  const across = f32(f32(f32(x) - f32(e.cx)) / f32(e.ax)), down = f32(f32(f32(y) - f32(e.cy)) / f32(e.ay));
  return f32(Math.sqrt(f32(f32(across * across) + f32(down * down))));
}

function smoothWeight(radius: number, inner = HEAD_INNER): number {
  const ramp = Math.min(Math.max(f32(f32(1 - radius) / f32(1 - inner)), 0), 1);
  return f32(ramp * ramp * (3 - 2 * ramp));
}

/** The head ellipse grown by PERSON_SCALE: how far the head layer reaches with the matte (_person_ellipse). */
function personEllipse(points: Tensor): Ellipse {
  const e = headEllipse(points);
  return { ...e, ax: e.ax * PERSON_SCALE, ay: e.ay * PERSON_SCALE };
}

/** 1 above the chin row, falling to 0 NECK_FADE face sides below it (landmarks.scene.compositing._neck), at frame row y. */
function neck(y: number, chin: number, side: number): number {
  return Math.min(Math.max(f32(f32(f32(chin + NECK_FADE * side) - f32(y)) / f32(NECK_FADE * side)), 0), 1);
}

/** With the matte, how much the point (x, y) moves with the head (landmarks.scene.compositing._person_weight). */
function personWeight(ellipses: Ellipse[], x: number, y: number, chin: number, side: number,
                      inner = PERSON_INNER): number {
  let radius = Infinity;
  for (const e of ellipses) radius = Math.min(radius, radiusAt(e, x, y));
  const ramp = f32(Math.min(Math.max(f32(f32(1 - radius) / f32(1 - inner)), 0), 1) * neck(y, chin, side));
  return f32(ramp * ramp * (3 - 2 * ramp));
}

/** Whether grid + shift folds somewhere (landmarks.scene.compositing._folds: the TPS's own foldedFraction, in grid steps). */
function folds(gridX: Float64Array, gridY: Float64Array, shiftX: Float64Array, shiftY: Float64Array): boolean {
  const rows = gridY.length, cols = gridX.length;
  if (rows < 2 || cols < 2) return false;
  const mapX = new Float64Array(rows * cols), mapY = new Float64Array(rows * cols);
  for (let j = 0, p = 0; j < rows; j++) {
    for (let i = 0; i < cols; i++, p++) { mapX[p] = gridX[i] + shiftX[p]; mapY[p] = gridY[j] + shiftY[p]; }
  }
  return foldedFraction(mapX, mapY, rows, cols) > 0;
}

/** Where the head layer would show pixels from beyond a frame edge, a factor fading it to none at that edge over
 * EDGE_RAMP times its largest reach beyond it, at least EDGE_CELLS grid steps (landmarks.scene.compositing._edge_fade); null
 * where no edge is reached EDGE_REACH pixels or more. */
function edgeFade(gridX: Float64Array, gridY: Float64Array, shiftX: Float64Array, shiftY: Float64Array,
                  height: number, width: number, step: number): Float32Array | null {
  const rows = gridY.length, cols = gridX.length;
  let fade: Float32Array | null = null;
  // the left, top, right and bottom edges in turn: along x (left, right) or y, the far one past width - 1 or height - 1
  for (let edge = 0; edge < 4; edge++) {
    const alongX = edge % 2 === 0, far = edge >= 2, last = alongX ? width - 1 : height - 1;
    let reach = -Infinity;
    for (let j = 0, p = 0; j < rows; j++) {
      for (let i = 0; i < cols; i++, p++) {
        const moved = alongX ? gridX[i] + shiftX[p] : gridY[j] + shiftY[p];  // how far beyond the edge it reads
        reach = Math.max(reach, far ? moved - last : -moved);
      }
    }
    if (reach < EDGE_REACH) continue;
    const span = Math.max(EDGE_RAMP * reach, EDGE_CELLS * step);
    const next: Float32Array = fade ?? new Float32Array(rows * cols).fill(1);
    for (let j = 0, p = 0; j < rows; j++) {
      for (let i = 0; i < cols; i++, p++) {
        const at = alongX ? gridX[i] : gridY[j], distance = far ? last - at : at;  // from the edge, inward
        const ramp = Math.min(Math.max(distance / span, 0), 1);
        next[p] = f32(next[p] * f32(ramp * ramp * (3 - 2 * ramp)));
      }
    }
    fade = next;
  }
  return fade;
}

/** How much of its motion each grid point of the head layer takes: the head weight, faded toward the frame edges
 * it would reach past, its ramp starting further in (INNER_RETRIES) until it does not fold
 * (landmarks.scene.compositing._fold_free_weight). */
function foldFreeWeight(ellipses: Ellipse[], gridX: Float64Array, gridY: Float64Array, shiftX: Float64Array,
                        shiftY: Float64Array, chin: number, side: number, person: boolean, box: Box, height: number,
                        width: number): Float32Array {
  const rows = gridY.length, cols = gridX.length, count = rows * cols;
  const weight = new Float32Array(count), movedX = new Float64Array(count), movedY = new Float64Array(count);
  const [x0, y0, x1, y1] = box;
  const clipped = x0 === 0 || y0 === 0 || x1 === width || y1 === height;  // only then can it reach past an edge
  const step = cols > 1 ? gridX[1] - gridX[0] : 1;
  for (const lower of INNER_RETRIES) {
    for (let j = 0, p = 0; j < rows; j++) {
      for (let i = 0; i < cols; i++, p++) {
        let w = 0;
        if (person) w = personWeight(ellipses, gridX[i], gridY[j], chin, side, PERSON_INNER - lower);
        else for (const e of ellipses) w = Math.max(w, smoothWeight(radiusAt(e, gridX[i], gridY[j]), HEAD_INNER - lower));
        weight[p] = w;
      }
    }
    if (clipped) {
      for (let p = 0; p < count; p++) { movedX[p] = shiftX[p] * weight[p]; movedY[p] = shiftY[p] * weight[p]; }
      const fade = edgeFade(gridX, gridY, movedX, movedY, height, width, step);
      if (fade) for (let p = 0; p < count; p++) weight[p] = f32(weight[p] * fade[p]);
    }
    for (let p = 0; p < count; p++) { movedX[p] = shiftX[p] * weight[p]; movedY[p] = shiftY[p] * weight[p]; }
    if (!folds(gridX, gridY, movedX, movedY)) break;
  }
  return weight;
}

function boxOf(ellipses: Ellipse[], height: number, width: number, margin = 2): Box | null {
  const x0 = Math.max(Math.floor(Math.min(...ellipses.map((e) => e.cx - e.ax))) - margin, 0);
  const y0 = Math.max(Math.floor(Math.min(...ellipses.map((e) => e.cy - e.ay))) - margin, 0);
  const x1 = Math.min(Math.ceil(Math.max(...ellipses.map((e) => e.cx + e.ax))) + margin + 1, width);
  const y1 = Math.min(Math.ceil(Math.max(...ellipses.map((e) => e.cy + e.ay))) + margin + 1, height);
  return x0 >= x1 || y0 >= y1 ? null : [x0, y0, x1, y1];
}

/** (x0, y0, x1, y1) bounding every given face's head region, clipped to the frame; null if outside it
 * (landmarks.scene.compositing.head_box). */
export function headBox(landmarksList: Tensor[], height: number, width: number, margin = 2): Box | null {
  return boxOf(landmarksList.map(headEllipse), height, width, margin);
}

/** (h, w) uint8 of a region at (x0, y0): 1 inside any head ellipse shrunk by 1.5 pixels
 * (landmarks.scene.compositing._inside_heads). */
function insideHeads(ellipses: Ellipse[], height: number, width: number, x0: number, y0: number): Uint8Array {
  const mask = new Uint8Array(height * width);
  for (const e of ellipses) {
    fillEllipse(mask, width, height, rint((e.cx - x0) * 16), rint((e.cy - y0) * 16),
                rint(Math.max(e.ax - 1.5, 0) * 16), rint(Math.max(e.ay - 1.5, 0) * 16));
  }
  return mask;
}

// ---- blur (landmarks.scene.compositing.blur) ---------------------------------------------------------------------------

/** Gaussian blur at any sigma, large sigmas on a shrunk copy (landmarks.scene.compositing.blur): (h, w, channels) float32. */
function blur(image: Float32Array, width: number, height: number, channels: number, sigma: number): Float32Array {
  if (sigma <= 6) return gaussianBlurF32(image, width, height, channels, Math.max(sigma, 0.1));
  const factor = sigma / 3;
  const smallW = Math.max(1, rint(width / factor)), smallH = Math.max(1, rint(height / factor));
  const small = resizeArea({ data: image, width, height, channels }, smallW, smallH);
  const blurred = gaussianBlurF32(small, smallW, smallH, channels, 3);
  return resizeLinear({ data: blurred, width: smallW, height: smallH, channels }, width, height);
}

/** landmarks.scene.compositing.blur on a tensor: (h, w[, c]) float32 (the tests compare it with OpenCV's). */
export function sceneBlur(image: Tensor<Float32Array>, sigma: number): Tensor<Float32Array> {
  const [height, width, channels = 1] = image.shape;
  return tensor(blur(Float32Array.from(image.data), width, height, channels, sigma), [...image.shape]);
}

/** The composite's masks on their own (the tests compare them with OpenCV's): "ellipse" (cv2.ellipse as
 * _inside_heads calls it: centre (x, y), semi-axes (a, b) in pixels), "hull" (cv2.fillConvexPoly of the
 * cv2.convexHull of integer points), "distance" (cv2.distanceTransform of the hull's outside, DIST_L2, 3). */
export function sceneMask(kind: "ellipse" | "hull" | "distance", height: number, width: number, values: number[]
                          ): Tensor<Uint8Array> | Tensor<Float32Array> {
  if (kind === "ellipse") {
    const mask = new Uint8Array(height * width);
    for (let i = 0; i < values.length; i += 4) {
      insideHeads([{ cx: values[i], cy: values[i + 1], ax: values[i + 2], ay: values[i + 3] }], height, width, 0, 0)
        .forEach((v, j) => { mask[j] |= v; });
    }
    return tensor(mask, [height, width]);
  }
  const hull = new Uint8Array(height * width);
  fillConvexPoly(hull, width, height, convexHull(values), 0);
  return kind === "hull" ? tensor(hull, [height, width])
    : tensor(distanceTransform(hull, width, height, true), [height, width]);
}

// ---- the composite ------------------------------------------------------------------------------------------

function checkScene(scene: Tensor<Uint8Array>): void {
  if (scene.shape.length !== 3 || scene.shape[2] !== 3 || !(scene.data instanceof Uint8Array)) {
    throw new Error(`scene must be (H, W, 3) uint8, got [${scene.shape}]`);
  }
}

function rows(points: Tensor, indices: number[], dx: number, dy: number): Tensor<Float64Array> {
  const out = new Float64Array(indices.length * 2);
  for (let i = 0; i < indices.length; i++) {
    out[2 * i] = points.data[2 * indices[i]] - dx;
    out[2 * i + 1] = points.data[2 * indices[i] + 1] - dy;
  }
  return tensor(out, [indices.length, 2]);
}

/** The head layer, in place in `output` (the box only): the scene moved by the head's rigid motion plus a TPS that
 * lands its outline on the target's, fading to none at the head ellipses' edge; with layers, only the person moves
 * (down to the chin, fading below it, out to the grown ellipses) and the background plate fills what it uncovers
 * (landmarks.scene.compositing.composite_face's head layer, _person_weight, _keep_background). */
function headLayer(scene: Tensor<Uint8Array>, output: Uint8Array, scenePoints: Tensor, targetPoints: Tensor,
                   motion: Affine, ellipses: Ellipse[], box: Box, side: number, layers: SceneLayers | null): void {
  const [x0, y0, x1, y1] = box, w = x1 - x0, h = y1 - y0, [height, width] = scene.shape;
  const moved = transformPoints(scenePoints, motion);
  const step = Math.max(4, rint(side / HEAD_GRID_CELLS));
  const warp = tpsGridMap(rows(moved, HEAD_WARP_INDEX, x0, y0), rows(targetPoints, HEAD_WARP_INDEX, x0, y0), h, w,
                          { gridStep: step });
  const inverse = invertAffine(motion), { xs, ys } = warp.grid, cols = xs.length, count = xs.length * ys.length;
  const shiftX = new Float64Array(count), shiftY = new Float64Array(count);
  let largest = 0;
  for (let j = 0, p = 0; j < ys.length; j++) {
    for (let i = 0; i < cols; i++, p++) {
      const mx = warp.mapX[p] + x0, my = warp.mapY[p] + y0;
      shiftX[p] = inverse[0] * mx + inverse[1] * my + inverse[2] - (xs[i] + x0);
      shiftY[p] = inverse[3] * mx + inverse[4] * my + inverse[5] - (ys[j] + y0);
      largest = Math.max(largest, Math.abs(shiftX[p]), Math.abs(shiftY[p]));
    }
  }
  if (!(largest > STILL)) return;
  const chin = Math.max(scenePoints.data[17], targetPoints.data[17]), sides = Math.max(side, faceSide(scenePoints));
  const gridX = new Float64Array(xs.length), gridY = new Float64Array(ys.length);  // loops: no closures made per frame
  for (let i = 0; i < xs.length; i++) gridX[i] = xs[i] + x0;
  for (let j = 0; j < ys.length; j++) gridY[j] = ys[j] + y0;
  const weight = foldFreeWeight(ellipses, gridX, gridY, shiftX, shiftY, chin, sides, layers !== null, box, height,
                                width);
  for (let p = 0; p < count; p++) {
    shiftX[p] *= weight[p];
    shiftY[p] *= weight[p];
  }
  // the scene's source position of each box pixel, dense, in WebAssembly memory to be remapped there (remap_wasm.ts)
  const sources = sceneSources(scene);
  const [slot] = sources ? sources.mapSlots(1, w * h) : [{ mapX: new Float32Array(w * h), mapY: new Float32Array(w * h) }];
  const sourceX = slot.mapX, sourceY = slot.mapY;
  if (!sources?.densifySlot(slot, warp.grid, shiftX, shiftY)) {
    densifyGrid(warp.grid, shiftX, sourceX);
    densifyGrid(warp.grid, shiftY, sourceY);
  }
  for (let y = 0, i = 0; y < h; y++) {
    const row = f32(y0 + y);
    for (let x = 0; x < w; x++, i++) {
      sourceX[i] = f32(sourceX[i] + f32(x0 + x));
      sourceY[i] = f32(sourceY[i] + row);
    }
  }
  // interpolated, the field leaks a sub-pixel shift just past the ellipses: the scene stays there, bit for bit
  const inside = insideHeads(ellipses, h, w, x0, y0);
  if (layers) {  // ... and below the neck's fade
    for (let y = 0; y < h; y++) if (neck(y0 + y, chin, sides) <= 0) inside.fill(0, y * w, (y + 1) * w);
  }
  const movedHead = new Uint8Array(w * h * 3);
  if (sources) sources.remapSlot(slot, 0, "reflect", movedHead, inside);
  else remapCubic({ data: scene.data, width, height, channels: 3 }, sourceX, sourceY, "reflect", movedHead, inside);
  if (!layers) {
    for (let y = 0, i = 0; y < h; y++) {
      for (let x = 0, o = ((y0 + y) * width + x0) * 3; x < w; x++, i++, o += 3) {
        if (inside[i]) { output[o] = movedHead[3 * i]; output[o + 1] = movedHead[3 * i + 1]; output[o + 2] = movedHead[3 * i + 2]; }
      }
    }
    return;
  }
  // the background plate where the head moves off it: head + background (plate - head), background the matte's
  // outside (bilinearAt, its inside case here) at the source, as far as the pixel moves (up to MOVING pixels)
  const matte = layers.matte.data, plate = layers.plate.data, image = { data: matte, width, height, channels: 1 };
  const clamped = clampedView(output);  // its stores round half to even and saturate, as rint and the clip do
  for (let y = 0, i = 0; y < h; y++) {
    for (let x = 0, o = ((y0 + y) * width + x0) * 3; x < w; x++, i++, o += 3) {
      if (!inside[i]) continue;
      const sx = sourceX[i], sy = sourceY[i], dx = sx - (x0 + x), dy = sy - (y0 + y);
      const moving = f32(Math.min(f32(Math.sqrt(dx * dx + dy * dy)), MOVING) / MOVING);
      const mx = Math.floor(sx), my = Math.floor(sy);
      let weight: number;
      if (mx >= 0 && mx < width - 1 && my >= 0 && my < height - 1) {
        const a = sx - mx, b = sy - my, r0 = my * width + mx, r1 = r0 + width;
        weight = (matte[r0] * (1 - a) + matte[r0 + 1] * a) * (1 - b) + (matte[r1] * (1 - a) + matte[r1 + 1] * a) * b;
      } else weight = bilinearAt(image, sx, sy, "reflect");
      const background = f32((1 - f32(weight)) * moving), p = 3 * i;
      const r = movedHead[p], g = movedHead[p + 1], bl = movedHead[p + 2];
      clamped[o] = f32(r + f32(background * f32(plate[o] - r)));
      clamped[o + 1] = f32(g + f32(background * f32(plate[o + 1] - g)));
      clamped[o + 2] = f32(bl + f32(background * f32(plate[o + 2] - bl)));
    }
  }
}

let faceSources: CubicSources | null = null;

/** warpAffineCubic(crop, m, width, height, "replicate") (the synthesis into the frame's face box), in WebAssembly
 * where it runs (remap_wasm.ts): the same float32 positions as maps, the same bytes. */
function warpFace(crop: PixelImage<Uint8Array>, m: Affine, width: number, height: number): Uint8Array {
  faceSources = CubicSources.reload(faceSources, crop.data, 1, crop.width, crop.height);
  if (faceSources === null) return warpAffineCubic(crop, m, width, height, "replicate");
  const [slot] = faceSources.mapSlots(1, width * height), mapX = slot.mapX, mapY = slot.mapY;
  const m0 = f32(m[0]), m3 = f32(m[3]);
  for (let y = 0, i = 0; y < height; y++) {  // warpAffineCubic's positions, float32
    const mx = f32(y * m[1] + m[2]), my = f32(y * m[4] + m[5]);
    for (let x = 0; x < width; x++, i++) { mapX[i] = m0 * x + mx; mapY[i] = m3 * x + my; }
  }
  const out = new Uint8Array(width * height * 3);
  faceSources.remapSlot(slot, 0, "replicate", out);
  return out;
}

let cachedScene: CubicSources | null = null;

/** The scene in WebAssembly memory for remap_wasm.ts (kept while the same scene comes: a person's; null without
 * WebAssembly SIMD). */
function sceneSources(scene: Tensor<Uint8Array>): CubicSources | null {
  const [height, width] = scene.shape;
  cachedScene = CubicSources.of(cachedScene, scene.data, 1, width, height);
  return cachedScene;
}

/** Put a synthesised face into a scene frame, the head (hair) following it (landmarks.scene.compositing.composite_face).
 * scene: (H, W, 3) uint8; sceneLandmarks: (68, 2) the scene's own face; targetLandmarks: (68, 2) where the face is
 * drawn; faceCrop: (C, C, 3) uint8 the synthesis, a crop of the frame under cropMatrix (frame -> crop); layers: the
 * scene's person matte and background plate (only the person moves), or null (the whole head region moves). The
 * scene stays in WebAssembly memory for the next call with the same array (remap_wasm.ts): its values must not change
 * in between. */
export function compositeFace(scene: Tensor<Uint8Array>, sceneLandmarks: Tensor, targetLandmarks: Tensor,
                              faceCrop: Tensor<Uint8Array>, cropMatrix: Affine | number[],
                              layers: SceneLayers | null = null): Composite {
  checkScene(scene);
  checkPoints(sceneLandmarks, 68, "scene_landmarks");
  checkPoints(targetLandmarks, 68, "target_landmarks");
  const [height, width] = scene.shape;
  if (layers && (layers.matte.shape[0] !== height || layers.matte.shape[1] !== width
                 || layers.plate.shape[0] !== height || layers.plate.shape[1] !== width)) {
    throw new Error(`the layers must be the scene's size [${height}, ${width}]`);
  }
  const motion = similarityAffine(similarityProcrustes(sceneLandmarks, targetLandmarks, RIGID_INDEX));
  const heads = [headEllipse(sceneLandmarks), headEllipse(targetLandmarks)];
  // with the matte the head layer reaches further (hair beyond the head ellipse moves with the head)
  const ellipses = layers ? [personEllipse(sceneLandmarks), personEllipse(targetLandmarks)] : heads;
  const box = boxOf(ellipses, height, width);
  const output = Uint8Array.from(scene.data);
  if (!box) return { frame: tensor(output, [...scene.shape]), box: null, faceAlpha: null, headMotion: null };
  const [x0, y0, x1, y1] = box, side = faceSide(targetLandmarks);
  headLayer(scene, output, sceneLandmarks, targetLandmarks, motion, ellipses, box, side, layers);
  const frame = tensor(output, [...scene.shape]);

  // face layer, in the face's own box (the hull, its margin and feather): the synthesis, exactly inverse-warped
  const reach = Math.ceil((FACE_MARGIN + FACE_FEATHER) * side) + 2;
  const [left, right, mouth] = faceGeometry(targetLandmarks), t = targetLandmarks.data;
  const liftX = FOREHEAD_LIFT * ((left[0] + right[0]) / 2 - mouth[0]);
  const liftY = FOREHEAD_LIFT * ((left[1] + right[1]) / 2 - mouth[1]);
  const outline: number[] = [];
  for (let i = 0; i < 27; i++) outline.push(t[2 * i] + (i >= 17 ? liftX : 0), t[2 * i + 1] + (i >= 17 ? liftY : 0));
  const outlineX = outline.filter((_, i) => i % 2 === 0), outlineY = outline.filter((_, i) => i % 2 === 1);
  const fx0 = Math.max(Math.floor(Math.min(...outlineX)) - reach, x0);
  const fy0 = Math.max(Math.floor(Math.min(...outlineY)) - reach, y0);
  const fx1 = Math.min(Math.ceil(Math.max(...outlineX)) + reach + 1, x1);
  const fy1 = Math.min(Math.ceil(Math.max(...outlineY)) + reach + 1, y1);
  if (fx0 >= fx1 || fy0 >= fy1) return { frame, box, faceAlpha: null, headMotion: motion };
  const fw = fx1 - fx0, fh = fy1 - fy0, pixels = fw * fh;
  const c = cropMatrix;
  const faceMatrix: Affine = [c[0], c[1], c[2] + c[0] * fx0 + c[1] * fy0, c[3], c[4], c[5] + c[3] * fx0 + c[4] * fy0];
  const cropSide = faceCrop.shape[0];
  const crop = { data: faceCrop.data, width: faceCrop.shape[1], height: cropSide, channels: 3 };
  const face = warpFace(crop, faceMatrix, fw, fh);
  // the crop's inside (edge pixels in from its border) under a bilinear warp: a separable indicator, so per axis
  const edge = Math.max(1, Math.floor(cropSide / 32));
  const footprint = new Float32Array(pixels);
  for (let y = 0, i = 0; y < fh; y++) {
    for (let x = 0; x < fw; x++, i++) {
      const u = faceMatrix[0] * x + faceMatrix[1] * y + faceMatrix[2];
      footprint[i] = indicator(u, edge, cropSide) * indicator(faceMatrix[3] * x + faceMatrix[4] * y + faceMatrix[5], edge,
                                                              cropSide);
    }
  }
  const hull = new Uint8Array(pixels);
  fillConvexPoly(hull, fw, fh, convexHull(outline.map((v, i) => rint(v - (i % 2 === 0 ? fx0 : fy0)))), 0);
  const outside = distanceTransform(hull, fw, fh, true);
  const within = withinHead(heads, fw, fh, fx0, fy0);
  const alpha = new Float32Array(pixels);
  for (let i = 0; i < pixels; i++) {
    const inward = FACE_MARGIN * side + (FACE_FEATHER * side) / 2 - outside[i];
    const ramp = Math.min(Math.max(inward / (FACE_FEATHER * side), 0), 1);
    alpha[i] = ramp * ramp * (3 - 2 * ramp) * footprint[i] * (within ? within[i] : 1);
  }

  // colour match: a smooth offset that makes the face's edge agree with the head layer around it
  const head = new Float32Array(pixels * 3), faceF = new Float32Array(pixels * 3);
  for (let y = 0, i = 0; y < fh; y++) {
    for (let x = 0; x < fw; x++, i++) {
      const o = ((fy0 + y) * width + fx0 + x) * 3;
      for (let k = 0; k < 3; k++) { head[3 * i + k] = output[o + k]; faceF[3 * i + k] = face[3 * i + k]; }
    }
  }
  const insideHull = distanceTransform(hull, fw, fh, false);
  const band = new Float32Array(pixels);
  let bandSum = 0;
  for (let i = 0; i < pixels; i++) {
    band[i] = hull[i] > 0 && insideHull[i] < COLOUR_BAND * side && footprint[i] > 0.99 ? 1 : 0;
    bandSum += band[i];
  }
  if (bandSum > 16) {
    // the difference on the band (3 channels) and the band (the 4th) blurred together: each channel as on its own
    const sigma = COLOUR_SIGMA * side, stacked = new Float32Array(pixels * 4), total = [0, 0, 0];
    for (let i = 0; i < pixels; i++) {
      for (let k = 0; k < 3; k++) {
        stacked[4 * i + k] = (head[3 * i + k] - faceF[3 * i + k]) * band[i];
        total[k] += stacked[4 * i + k];
      }
      stacked[4 * i + 3] = band[i];
    }
    const blurred = blur(stacked, fw, fh, 4, sigma);
    for (let i = 0; i < pixels; i++) {
      const spread = blurred[4 * i + 3];
      for (let k = 0; k < 3; k++) {
        const offset = spread <= 1e-3 ? total[k] / bandSum : f32(blurred[4 * i + k] / Math.max(spread, f32(1e-3)));
        faceF[3 * i + k] += Math.min(Math.max(offset, -COLOUR_LIMIT), COLOUR_LIMIT);
      }
    }
  }
  const clamped = clampedView(output);  // its stores round half to even and saturate, as rint and the clip do
  for (let y = 0, i = 0; y < fh; y++) {  // head + (face - head) * alpha
    for (let x = 0; x < fw; x++, i++) {
      const o = ((fy0 + y) * width + fx0 + x) * 3;
      for (let k = 0; k < 3; k++) {
        clamped[o + k] = f32(f32(f32(faceF[3 * i + k] - head[3 * i + k]) * alpha[i]) + head[3 * i + k]);
      }
    }
  }
  const fullAlpha = new Float32Array((y1 - y0) * (x1 - x0));
  for (let y = 0; y < fh; y++) {
    fullAlpha.set(alpha.subarray(y * fw, (y + 1) * fw), (fy0 - y0 + y) * (x1 - x0) + fx0 - x0);
  }
  return { frame, box, faceAlpha: tensor(fullAlpha, [y1 - y0, x1 - x0]), headMotion: motion };
}

/** The crop's inside (`edge` pixels in from the border of a `side` crop) at v under a bilinear warp, along one axis. */
function indicator(v: number, edge: number, side: number): number {
  const v0 = Math.floor(v), a = v - v0;
  return (v0 >= edge && v0 < side - edge ? 1 - a : 0) + (v0 + 1 >= edge && v0 + 1 < side - edge ? a : 0);
}

/** 1 inside the head regions, ramping to 0 over their outermost 5 %; null when the whole box lies inside one of
 * them (landmarks.scene.compositing._within_head). */
function withinHead(ellipses: Ellipse[], width: number, height: number, x0: number, y0: number): Float32Array | null {
  const corners = [[x0, y0], [x0 + width - 1, y0], [x0, y0 + height - 1], [x0 + width - 1, y0 + height - 1]];
  if (ellipses.some((e) => corners.every(([x, y]) => radiusAt(e, x, y) <= f32(0.95)))) return null;
  // radiusAt's squared terms, float32: across per column, down per row
  const across = ellipses.map((e) => {
    const squares = new Float32Array(width);
    for (let x = 0; x < width; x++) {
      const a = f32(f32(f32(x0 + x) - f32(e.cx)) / f32(e.ax));
      squares[x] = a * a;
    }
    return squares;
  });
  const down = new Float32Array(ellipses.length), out = new Float32Array(width * height);
  for (let y = 0, i = 0; y < height; y++) {
    ellipses.forEach((e, k) => { const d = f32(f32(f32(y0 + y) - f32(e.cy)) / f32(e.ay)); down[k] = d * d; });
    for (let x = 0; x < width; x++, i++) {
      let radius = Infinity;
      for (let k = 0; k < across.length; k++) radius = Math.min(radius, f32(Math.sqrt(f32(across[k][x] + down[k]))));
      out[i] = Math.min(Math.max(f32(f32(1 - radius) / f32(0.05)), 0), 1);
    }
  }
  return out;
}
