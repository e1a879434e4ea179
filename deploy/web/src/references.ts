// The warp-guided generator's references: the N shots nearest the target, each TPS-warped onto it with a mask of
// where the warp is valid (landmarks/warp/tps.py nearest_shots, landmark_distance, warp_references), and with the shots'
// irises, each warp bent to carry its shot's iris to where the target looks (iris_warp.ts).

import { LEFT_EYE, RIGHT_EYE } from "./geometry.js";
import { DenseMaps, alignIrises } from "./iris_warp.js";
import { densifyGrid, remapCubic } from "./remap.js";
import { CubicSources, MapSlot } from "./remap_wasm.js";
import { Tensor, ascending, tensor } from "./tensor.js";
import { GridMap, WarpMethod, tpsGridMaps, warpValidMask } from "./tps.js";

// ---- references for the warp-guided generator ---------------------------------------------------------------

/** Mean point distance over `second`'s eye-centre distance (landmarks.warp.tps.landmark_distance): (68, 2), (68, 2) ->
 * number; NaN where either has NaN rows or `second` has no eye distance. */
export function landmarkDistance(first: Tensor, second: Tensor, firstOffset = 0): number {
  const a = first.data, b = second.data, count = second.shape[0];
  let total = 0;
  for (let i = 0, o = firstOffset; i < count; i++, o += 2) {
    total += Math.hypot(a[o] - b[2 * i], a[o + 1] - b[2 * i + 1]);
  }
  const eyes = Math.hypot(meanOf(b, LEFT_EYE, 0) - meanOf(b, RIGHT_EYE, 0), meanOf(b, LEFT_EYE, 1) - meanOf(b, RIGHT_EYE, 1));
  return eyes > 0 ? total / count / eyes : NaN;
}

/** The mean of coordinate c of points `indices` of (N, 2) flat `points`, summed in order. */
function meanOf(points: ArrayLike<number>, indices: number[], c: number): number {
  let sum = 0;
  for (const i of indices) sum += points[2 * i + c];
  return sum / indices.length;
}

/** Indices of the `count` shots nearest the target (landmarkDistance, ties by index; shots with NaN last)
 * (landmarks.warp.tps.nearest_shots). shotLandmarks: (K, 68, 2); targetLandmarks: (68, 2) -> min(count, K) indices. */
export function nearestShots(shotLandmarks: Tensor, targetLandmarks: Tensor, count: number): number[] {
  const shots = shotLandmarks.shape[0], stride = targetLandmarks.data.length;
  const distances: number[] = new Array(shots);
  for (let k = 0; k < shots; k++) {
    const distance = landmarkDistance(shotLandmarks, targetLandmarks, k * stride);
    distances[k] = Number.isNaN(distance) ? Infinity : distance;
  }
  const order = Array.from({ length: shots }, (_, k) => k).sort((p, q) => distances[p] - distances[q] || p - q);
  return order.slice(0, Math.max(1, Math.min(count, shots)));
}

let denseX = new Float32Array(0), denseY = new Float32Array(0);
let cubicSources: CubicSources | null = null;

/** The shots in WebAssembly memory for remap_wasm.ts (kept while the same shots come; null without WebAssembly
 * SIMD). */
function shotSources(shots: Tensor<Uint8Array>): CubicSources | null {
  const [count, height, width] = shots.shape;
  cubicSources = CubicSources.of(cubicSources, shots.data, count, width, height);
  return cubicSources;
}

export interface References {
  warped: Tensor<Uint8Array>;  // (count, S, S, 3)
  masks: Tensor<Float32Array>;  // (count, S, S) in {0, 1}
  indices: number[];  // (count,)
  methods: WarpMethod[];  // per reference: how it was warped
}

/** The `count` nearest shots, each TPS-warped onto the target landmarks, with validity masks
 * (landmarks.warp.tps.warp_references). shots: (K, S, S, 3) uint8; shotLandmarks: (K, 68, 2); targetLandmarks: (68, 2),
 * all in the shots' pixels. With fewer than `count` shots the nearest ones repeat. With `irises` ((K, 2, 2) each
 * shot's iris centres, NaN where not found), the warps carry every iris to where the target looks (`gaze` (2, 2),
 * gaze.ts gazeOffsets; null or NaN: where the nearest shot's lands) by iris_warp.ts alignIrises. The shots stay in
 * WebAssembly memory for the next call with the same array (remap_wasm.ts): its values must not change in between. */
export function warpReferences(shots: Tensor<Uint8Array>, shotLandmarks: Tensor, targetLandmarks: Tensor, count: number,
                               gridStep = 4, irises: Tensor | null = null, gaze: Tensor | null = null): References {
  if (shots.shape.length !== 4 || shots.shape[3] !== 3 || !(shots.data instanceof Uint8Array)) {
    throw new Error(`shots must be (K, S, S, 3) uint8, got [${shots.shape}]`);
  }
  if (count < 1) throw new Error(`count must be >= 1, got ${count}`);
  if (irises !== null && irises.data.length !== shots.shape[0] * 4) {
    throw new Error(`irises must be (${shots.shape[0]}, 2, 2), got [${irises.shape}]`);
  }
  const nearest = nearestShots(shotLandmarks, targetLandmarks, count);
  const indices = Array.from({ length: count }, (_, i) => nearest[i % nearest.length]);
  const [, height, width] = shots.shape, pixels = height * width, points = shotLandmarks.shape.slice(1);
  const stride = points[0] * points[1];
  const unique = [...new Set(indices)].sort(ascending);
  const sets = unique.map((k) => tensor(shotLandmarks.data.slice(k * stride, (k + 1) * stride), points));
  const warps = tpsGridMaps(sets, targetLandmarks, height, width, { gridStep });
  const warped = new Uint8Array(count * pixels * 3), masks = new Float32Array(count * pixels);
  // each dense map in turn, in the same two buffers from frame to frame
  if (denseX.length !== pixels) { denseX = new Float32Array(pixels); denseY = new Float32Array(pixels); }
  const map = { mapX: denseX, mapY: denseY };
  const sources = shotSources(shots);
  const bent = irises === null ? null
    : bentMaps(warps, unique, [...new Set(indices)], irises, targetLandmarks, gaze, sources);
  const methods: WarpMethod[] = [];
  indices.forEach((index, slot) => {
    const warp = warps[unique.indexOf(index)];
    methods.push(warp.method);
    const first = indices.indexOf(index);
    const image = warped.subarray(slot * pixels * 3, (slot + 1) * pixels * 3);
    const mask = masks.subarray(slot * pixels, (slot + 1) * pixels);
    if (first < slot) {
      image.set(warped.subarray(first * pixels * 3, (first + 1) * pixels * 3));
      mask.set(masks.subarray(first * pixels, (first + 1) * pixels));
      return;
    }
    const shot = shots.data.subarray(index * pixels * 3, (index + 1) * pixels * 3);
    const irisMap = bent?.get(index);
    if (irisMap) {  // the dense maps bent for the irises: remapped, and their mask, as they are
      const mapX = irisMap.mapX.data, mapY = irisMap.mapY.data;
      if (sources) {  // the maps are in its memory (bentMaps)
        sources.remapSlot({ mapX, mapY }, index, "replicate", image);
        sources.validSlot({ mapX, mapY }, mask);
        return;
      }
      remapCubic({ data: shot, width, height, channels: 3 }, mapX, mapY, "replicate", image);
      warpValidMask({ mapX, mapY }, height, width, mask);
      return;
    }
    // the dense maps, the remap and the mask in WebAssembly (remap_wasm.ts), else here
    if (warp.method !== "identity" && sources?.warp(index, warp.grid, warp.mapX, warp.mapY, "replicate", image, mask)) return;
    densifyGrid(warp.grid, warp.mapX, map.mapX);
    densifyGrid(warp.grid, warp.mapY, map.mapY);
    if (warp.method === "identity") image.set(shot);
    else if (sources) sources.remap(index, map.mapX, map.mapY, "replicate", image);
    else remapCubic({ data: shot, width, height, channels: 3 }, map.mapX, map.mapY, "replicate", image);
    warpValidMask(map, height, width, mask);
  });
  return { warped: tensor(warped, [count, height, width, 3]), masks: tensor(masks, [count, height, width]), indices,
           methods };
}

let irisMaps: MapSlot[] = [];  // bentMaps' dense maps without WebAssembly, kept from frame to frame

/** Each shot's dense maps (warps[i] of shot unique[i]; the identity map, exact, for an "identity" warp, as
 * landmarks.warp.tps.warp_references makes it for the irises to bend) bent by alignIrises, `nearestFirst` (the unique
 * shots nearest first, as Python orders them: dict.fromkeys(indices)) -> shot index -> its maps. With `sources`, the
 * maps are made in its memory (densified there), to be remapped there as they are (CubicSources.remapSlot). */
function bentMaps(warps: GridMap[], unique: number[], nearestFirst: number[], irises: Tensor, target: Tensor,
                  gaze: Tensor | null, sources: CubicSources | null): Map<number, DenseMaps> {
  const { height, width } = warps[0].grid, pixels = height * width;
  if (sources === null && (irisMaps.length < unique.length || irisMaps[0].mapX.length !== pixels)) {
    irisMaps = Array.from({ length: unique.length }, () => ({ mapX: new Float32Array(pixels), mapY: new Float32Array(pixels) }));
  }
  const slots = sources ? sources.mapSlots(nearestFirst.length, pixels) : irisMaps;
  const maps = nearestFirst.map((index, i) => {
    const warp = warps[unique.indexOf(index)], { mapX, mapY } = slots[i];
    if (warp.method === "identity") {
      for (let p = 0; p < pixels; p++) { mapX[p] = p % width; mapY[p] = Math.floor(p / width); }
    } else if (!sources?.densifySlot(slots[i], warp.grid, warp.mapX, warp.mapY)) {
      densifyGrid(warp.grid, warp.mapX, mapX);
      densifyGrid(warp.grid, warp.mapY, mapY);
    }
    return { mapX: tensor(mapX, [height, width]), mapY: tensor(mapY, [height, width]) };
  });
  const shotIrises = new Float64Array(4 * nearestFirst.length);
  for (let i = 0; i < nearestFirst.length; i++) {
    shotIrises.set(irises.data.subarray(4 * nearestFirst[i], 4 * nearestFirst[i] + 4), 4 * i);
  }
  alignIrises(maps, tensor(shotIrises, [nearestFirst.length, 2, 2]), target, gaze);
  return new Map(nearestFirst.map((index, i) => [index, maps[i]]));
}
