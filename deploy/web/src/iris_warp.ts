// The shots' irises warped to where the target looks (issue 40: one iris, where the driver looks):
// landmarks/parts/eyes/iris_shift.py (landed, _eye_box, iris_along, shift_iris, align_irises) on dense backward maps (output
// pixel p samples the source at map(p)), each (H, W) float32 flat.
//
// Before the shots are sampled, each reference's warp is bent inside each eye of the target (its 68 points'
// corners): a band of the eye around the warped iris moves rigidly along the corner line onto the target's gaze
// (gaze.ts gazeOffsets' first coordinate), or where no gaze is known onto where the nearest shot's iris lands; the
// rest of the eye is stretched on one side and squeezed on the other, back to the warp as it was at the corners and
// above and below the lids. Every reference then shows its own iris at the same place.
//
// Python samples the old map with cv2.remap (INTER_LINEAR, BORDER_REPLICATE); here bilinearAt does the same at the
// float position (remap.ts: OpenCV 5 samples there too).

import { eyeAxes } from "./gaze.js";
import { bilinearAt } from "./remap.js";
import { Tensor } from "./tensor.js";

/** Half-width, in eye widths along the corner line, of the band around the iris that moves rigidly. */
export const IRIS_PLATEAU = 0.25;
/** The warp is unchanged from this far from the eye's centre on, along the corner line (eye widths). */
export const IRIS_REACH = 0.6;
/** Across the corner line: the full shift within the first distance from it, none from the second (eye widths). */
export const IRIS_BAND: [number, number] = [0.3, 0.45];
/** An iris moves at most this many eye widths. */
export const IRIS_MAX_SHIFT = 0.25;

/** A dense backward map: mapX, mapY (H, W) float32 source pixel coordinates. */
export interface DenseMaps { mapX: Tensor<Float32Array>; mapY: Tensor<Float32Array> }

type Box = [number, number, number, number];

/** Where a backward map puts source `point` (landmarks.parts.eyes.iris_shift.landed): the output pixel whose map is nearest it
 * (searched within `box` (x0, y0, x1, y1) when given), refined by one Newton step on the map's local Jacobian ->
 * [x, y], NaN when the map never comes within 2 pixels of it there. */
export function landed(maps: DenseMaps, point: ArrayLike<number>, box: Box | null = null): [number, number] {
  const [height, width] = maps.mapX.shape, mx = maps.mapX.data, my = maps.mapY.data;
  const px = point[0], py = point[1];
  const x0 = box === null ? 0 : Math.max(box[0], 0), y0 = box === null ? 0 : Math.max(box[1], 0);
  const x1 = box === null ? width : Math.min(box[2], width), y1 = box === null ? height : Math.min(box[3], height);
  if (x1 <= x0 || y1 <= y0) return [NaN, NaN];
  let best = Infinity, row = -1, column = -1;
  for (let y = y0; y < y1; y++) {
    for (let x = x0, o = y * width + x0; x < x1; x++, o++) {
      const dx = mx[o] - px, dy = my[o] - py, distance = dx * dx + dy * dy;
      if (distance < best || row < 0) { best = distance; row = y; column = x; }  // the first of equals, as argmin
    }
  }
  if (!(best <= 4.0)) return [NaN, NaN];
  const r0 = Math.max(row - 1, 0), r1 = Math.min(row + 1, height - 1);
  const c0 = Math.max(column - 1, 0), c1 = Math.min(column + 1, width - 1);
  if (r1 === r0 || c1 === c0) return [column, row];
  // the map's local Jacobian, its differences in float32 as numpy takes them
  const across = (map: Float32Array) => Math.fround(map[row * width + c1] - map[row * width + c0]) / (c1 - c0);
  const down = (map: Float32Array) => Math.fround(map[r1 * width + column] - map[r0 * width + column]) / (r1 - r0);
  const at = row * width + column;
  const step = solve2(across(mx), down(mx), across(my), down(my), px - mx[at], py - my[at]);
  if (step === null) return [column, row];
  const clip = (v: number) => Math.min(Math.max(v, -1.5), 1.5);
  return [column + clip(step[0]), row + clip(step[1])];
}

/** A 2 x 2 system by LU with partial pivoting, as np.linalg.solve (LAPACK gesv); null where it is singular. */
function solve2(a: number, b: number, c: number, d: number, e: number, g: number): [number, number] | null {
  if (Math.abs(c) > Math.abs(a)) [a, b, c, d, e, g] = [c, d, a, b, g, e];
  if (a === 0) return null;
  const l = c / a, u = d - l * b;
  if (u === 0) return null;
  const y = (g - l * e) / u;
  return [(e - b * y) / a, y];
}

/** (x0, y0, x1, y1) integer pixel bounds of the region shiftIris may change around an eye
 * (landmarks.parts.eyes.iris_shift._eye_box). */
export function eyeBox(centre: [number, number], axis: [number, number], width: number): Box {
  const across = [-axis[1], axis[0]];
  let lowX = Infinity, lowY = Infinity, highX = -Infinity, highY = -Infinity;
  for (const u of [-IRIS_REACH, IRIS_REACH]) {
    for (const v of [-IRIS_BAND[1], IRIS_BAND[1]]) {
      const x = centre[0] + width * (u * axis[0] + v * across[0]);
      const y = centre[1] + width * (u * axis[1] + v * across[1]);
      lowX = Math.min(lowX, x); lowY = Math.min(lowY, y); highX = Math.max(highX, x); highY = Math.max(highY, y);
    }
  }
  return [Math.floor(lowX), Math.floor(lowY), Math.ceil(highX) + 1, Math.ceil(highY) + 1];
}

/** Where a shot's iris centre (`iris` [x, y], shot pixels) lands along the target's eye `eye` (its 68 points
 * `landmarks`), in eye widths from the eye's centre (landmarks.parts.eyes.iris_shift.iris_along); NaN when it does not land in
 * the eye's region. */
export function irisAlong(maps: DenseMaps, iris: ArrayLike<number>, landmarks: Tensor, eye: number): number {
  if (!(Number.isFinite(iris[0]) && Number.isFinite(iris[1]))) return NaN;
  const { centre, axis, width } = eyeAxes(landmarks.data, eye);
  if (!(width >= 1)) return NaN;
  const [x, y] = landed(maps, iris, eyeBox(centre, axis, width));
  if (!(Number.isFinite(x) && Number.isFinite(y))) return NaN;
  return ((x - centre[0]) * axis[0] + (y - centre[1]) * axis[1]) / width;
}

/** np.interp(x, xp, fp) for increasing xp: clamped to fp's ends outside. */
function interp(x: number, xp: number[], fp: number[]): number {
  const last = xp.length - 1;
  if (x >= xp[last]) return fp[last];
  if (x < xp[0]) return fp[0];
  let j = 0;
  while (j < last - 1 && xp[j + 1] <= x) j++;
  if (xp[j] === x) return fp[j];
  return ((fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])) * (x - xp[j]) + fp[j];
}

/** The maps with eye `eye` of the target's 68 points `landmarks` bent so that what they showed at `start` along the
 * corner line (eye widths from the eye's centre) shows at `end` (landmarks.parts.eyes.iris_shift.shift_iris); in place (only the
 * eye's box changes). Returns whether they changed. */
export function shiftIris(maps: DenseMaps, landmarks: Tensor, eye: number, start: number, end: number): boolean {
  const { centre, axis, width } = eyeAxes(landmarks.data, eye);
  end = Math.min(Math.max(end, start - IRIS_MAX_SHIFT), start + IRIS_MAX_SHIFT);
  const plateau = Math.min(IRIS_PLATEAU, IRIS_REACH - 0.05 - Math.max(Math.abs(start), Math.abs(end)));
  const usable = Number.isFinite(start) && Number.isFinite(end) && width >= 1 && plateau > 0.02;
  if (!usable || Math.abs(end - start) < 1e-3) return false;
  const [height, imageWidth] = maps.mapX.shape;
  let [x0, y0, x1, y1] = eyeBox(centre, axis, width);
  x0 = Math.max(x0, 0); y0 = Math.max(y0, 0); x1 = Math.min(x1, imageWidth); y1 = Math.min(y1, height);
  if (x1 <= x0 || y1 <= y0) return false;
  const xp = [-IRIS_REACH, end - plateau, end + plateau, IRIS_REACH];
  const fp = [-IRIS_REACH, start - plateau, start + plateau, IRIS_REACH];
  const sources = [maps.mapX, maps.mapY].map((map) => ({ data: map.data, width: imageWidth, height, channels: 1 }));
  const boxWidth = x1 - x0, bent = [new Float32Array(boxWidth * (y1 - y0)), new Float32Array(boxWidth * (y1 - y0))];
  for (let y = y0; y < y1; y++) {
    for (let x = x0; x < x1; x++) {
      const u = ((x - centre[0]) * axis[0] + (y - centre[1]) * axis[1]) / width;
      const v = ((x - centre[0]) * -axis[1] + (y - centre[1]) * axis[0]) / width;
      const weight = Math.min(Math.max((IRIS_BAND[1] - Math.abs(v)) / (IRIS_BAND[1] - IRIS_BAND[0]), 0), 1);
      const moved = Math.abs(u) < IRIS_REACH ? interp(u, xp, fp) : u;  // beyond the reach: the warp as it was
      const shift = weight * (moved - u) * width;  // pixels along the axis, output -> where its map is read
      const sampleX = Math.fround(x + shift * axis[0]), sampleY = Math.fround(y + shift * axis[1]);
      const o = (y - y0) * boxWidth + x - x0;
      bent[0][o] = bilinearAt(sources[0], sampleX, sampleY, "replicate");
      bent[1][o] = bilinearAt(sources[1], sampleX, sampleY, "replicate");
    }
  }
  // written once every sample of the old map is read
  [maps.mapX, maps.mapY].forEach((map, c) => {
    for (let y = y0; y < y1; y++) {
      map.data.set(bent[c].subarray((y - y0) * boxWidth, (y - y0 + 1) * boxWidth), y * imageWidth + x0);
    }
  });
  return true;
}

/** The references' backward maps, nearest first, each bent so that its shot's iris (`irises` (N, 2, 2) shot pixels,
 * image-left eye first, NaN where not found) lands where the target looks: `gaze` (2, 2) (gaze.ts gazeOffsets of the
 * target's 68 points `landmarks`, first coordinate), or, where an eye's is NaN or no gaze is given, where the first
 * reference's iris lands (landmarks.parts.eyes.iris_shift.align_irises). Unlike Python's, in place: returns `maps` themselves. */
export function alignIrises(maps: DenseMaps[], irises: Tensor, landmarks: Tensor, gaze: Tensor | null = null
                            ): DenseMaps[] {
  if (irises.data.length !== maps.length * 4) {
    throw new Error(`irises must be (${maps.length}, 2, 2), got [${irises.shape}]`);
  }
  // every eye's start on the maps as they came, as Python measures them (loops: no closures made per frame)
  const starts: number[][] = [[], []];
  for (let eye = 0; eye < 2; eye++) {
    for (let k = 0; k < maps.length; k++) {
      starts[eye].push(irisAlong(maps[k], irises.data.subarray(4 * k + 2 * eye, 4 * k + 2 * eye + 2), landmarks, eye));
    }
  }
  for (let eye = 0; eye < 2; eye++) {
    const wanted = gaze === null ? NaN : gaze.data[2 * eye];
    const end = Number.isFinite(wanted) ? wanted : starts[eye][0];
    if (!Number.isFinite(end)) continue;
    for (let k = 0; k < maps.length; k++) {
      if (Number.isFinite(starts[eye][k])) shiftIris(maps[k], landmarks, eye, starts[eye][k], end);
    }
  }
  return maps;
}
