// The scene's layers for the composite: the person matte (landmarks/scene/person_matte.py person_matte: MediaPipe's selfie
// segmenter, selfie_segmentation.onnx) and the background plate (landmarks/scene/compositing.py background_plate, fill_in), with
// the OpenCV steps they use on uint8 pictures: cv2.resize (INTER_AREA, INTER_LINEAR), cv2.pyrDown, cv2.dilate with
// an elliptic structuring element.
//
// The uint8 resizes run on float32 (remap.ts) and round half to even, as OpenCV's float paths do; OpenCV's integer
// fixed-point linear resize of uint8 may differ from it by one grey level here and there.

import * as ort from "onnxruntime-web";

import { cropTransform } from "./geometry.js";
import { dilateEllipse, reflect101, resizeImage, roundHalfEven } from "./remap.js";
import { Tensor, tensor } from "./tensor.js";

export const SEGMENTER_FILE = "mediapipe/selfie_segmentation.onnx"; // landmarks.scene.person_matte.SEGMENTER_FILE, under models/
export const SEGMENTER_SIZE = 256;
export const PERSON_LEVEL = 0.1; // landmarks.scene.compositing.PERSON_LEVEL
export const PERSON_REACH = 0.03; // landmarks.scene.compositing.PERSON_REACH
export const PLATE_SIDE = 384; // landmarks.scene.compositing.PLATE_SIDE
export const PLATE_TRUST = 16; // landmarks.scene.compositing.PLATE_TRUST

/** The face's crop side in frame pixels (landmarks.scene.compositing.face_side). */
function faceSide(landmarks: Tensor): number {
  const m = cropTransform(landmarks, 1024);
  return 1024 / Math.sqrt(Math.abs(m[0] * m[4] - m[1] * m[3]));
}

function toUint8(values: ArrayLike<number>): Uint8Array {
  const out = new Uint8Array(values.length);
  for (let i = 0; i < out.length; i++) {
    const v = roundHalfEven(values[i]);
    out[i] = v < 0 ? 0 : v > 255 ? 255 : v;
  }
  return out;
}

/** cv2.resize of a (H, W[, C]) uint8 picture to (width, height): "area" (INTER_AREA) or "linear" (INTER_LINEAR);
 * the same size gives a copy, as OpenCV does. */
export function resizeUint8(image: Tensor<Uint8Array>, width: number, height: number, interpolation: "area" | "linear"
                            ): Tensor<Uint8Array> {
  const resized = resizeImage(tensor(Float32Array.from(image.data), [...image.shape]), width, height, interpolation);
  return tensor(toUint8(resized.data), resized.shape);
}


/** The selfie segmenter's session from the bytes of selfie_segmentation.onnx. */
export async function createSegmenter(model: Uint8Array): Promise<ort.InferenceSession> {
  if (typeof process !== "undefined" && typeof process.versions?.node === "string") ort.env.wasm.numThreads = 1;
  return ort.InferenceSession.create(model, { executionProviders: ["wasm"], graphOptimizationLevel: "all" });
}

/** How much each pixel is a person, hair and clothes too (landmarks.scene.person_matte.person_matte): the whole frame squashed
 * to 256 x 256 (INTER_AREA when both sides are larger, else INTER_LINEAR), RGB in [0, 1], through the net, its
 * probability resized back (INTER_LINEAR) and clipped. (H, W, 3) uint8 -> (H, W) float32 in [0, 1]. */
export async function personMatte(segmenter: ort.InferenceSession, image: Tensor<Uint8Array>): Promise<Tensor<Float32Array>> {
  const [height, width, channels] = image.shape;
  if (image.shape.length !== 3 || channels !== 3 || Math.min(height, width) < 1) {
    throw new Error(`image must be (H, W, 3) uint8, got [${image.shape}]`);
  }
  const side = SEGMENTER_SIZE;
  const small = resizeUint8(image, side, side, Math.min(height, width) > side ? "area" : "linear");
  const input = new Float32Array(small.data.length);
  for (let i = 0; i < input.length; i++) input[i] = small.data[i] / 255;
  const feed = { [segmenter.inputNames[0]]: new ort.Tensor("float32", input, [1, side, side, 3]) };
  const output = (await segmenter.run(feed))[segmenter.outputNames[0]];
  const probability = tensor(new Float32Array(output.data as Float32Array), [side, side]);
  const matte = resizeImage(probability, width, height, "linear");
  for (let i = 0; i < matte.data.length; i++) matte.data[i] = Math.min(Math.max(matte.data[i], 0), 1);
  return matte;
}




const PYRAMID = [1, 4, 6, 4, 1];

/** cv2.pyrDown of an (h, w, channels) float32 image: the 5 x 5 binomial filter, every other pixel, reflect-101 border,
 * to ((w + 1) / 2, (h + 1) / 2). */
export function pyrDown(src: Float32Array, height: number, width: number, channels: number
                        ): { data: Float32Array; height: number; width: number } {
  const h = (height + 1) >> 1, w = (width + 1) >> 1;
  const rows = new Float32Array(height * w * channels);
  for (let y = 0; y < height; y++) {
    for (let x = 0; x < w; x++) {
      for (let c = 0; c < channels; c++) {
        let sum = 0;
        for (let k = 0; k < 5; k++) sum += PYRAMID[k] * src[(y * width + reflect101(2 * x + k - 2, width)) * channels + c];
        rows[(y * w + x) * channels + c] = sum;
      }
    }
  }
  const out = new Float32Array(h * w * channels), line = w * channels;
  for (let y = 0; y < h; y++) {
    for (let i = 0; i < line; i++) {
      let sum = 0;
      for (let k = 0; k < 5; k++) sum += PYRAMID[k] * rows[reflect101(2 * y + k - 2, height) * line + i];
      out[y * line + i] = sum / 256;
    }
  }
  return { data: out, height: h, width: w };
}

/** Fill an image where it is unknown from the known pixels around (landmarks.scene.compositing.fill_in: push-pull, a pyramid of
 * weighted means, each level's holes taken from the next coarser level). image (h, w, C) float32, known (h, w)
 * float32 weights in [0, 1] -> (h, w, C) float32. trust: a level's mean is taken fully where at least 1 / trust of
 * its footprint is known. */
export function fillIn(image: Tensor<Float32Array>, known: Tensor<Float32Array>, trust = 1): Tensor<Float32Array> {
  const [height, width] = known.shape, channels = image.shape[2];
  const levels: { weighted: Float32Array; weight: Float32Array; height: number; width: number }[] = [];
  let weighted: Float32Array = new Float32Array(image.data.length), weight: Float32Array = Float32Array.from(known.data);
  for (let p = 0; p < height * width; p++) for (let c = 0; c < channels; c++) {
    weighted[p * channels + c] = image.data[p * channels + c] * known.data[p];
  }
  let h = height, w = width;
  while (Math.min(h, w) > 2) {
    levels.push({ weighted, weight, height: h, width: w });
    const down = pyrDown(weighted, h, w, channels);
    weighted = down.data;
    weight = pyrDown(weight, h, w, 1).data;
    h = down.height; w = down.width;
  }
  const sums = new Float64Array(channels);
  let total = 0;
  for (let p = 0; p < h * w; p++) {
    total += weight[p];
    for (let c = 0; c < channels; c++) sums[c] += weighted[p * channels + c];
  }
  let filled = new Float32Array(h * w * channels);
  for (let p = 0; p < h * w; p++) for (let c = 0; c < channels; c++) filled[p * channels + c] = sums[c] / Math.max(total, 1e-6);
  let fh = h, fw = w;
  for (const level of levels.reverse()) {
    const coarse = resizeImage(tensor(filled, [fh, fw, channels]), level.width, level.height, "linear").data;
    const next = new Float32Array(level.height * level.width * channels);
    for (let p = 0; p < level.height * level.width; p++) {
      const taken = Math.min(level.weight[p] * trust, 1), divisor = Math.max(level.weight[p], 1e-6);
      for (let c = 0; c < channels; c++) {
        const i = p * channels + c;
        next[i] = (level.weighted[i] / divisor) * taken + coarse[i] * (1 - taken);
      }
    }
    filled = next; fh = level.height; fw = level.width;
  }
  return tensor(filled, [height, width, channels]);
}

/** The scene's layers (landmarks.scene.compositing.background_plate): its person matte, clipped, and the background with the
 * person (and PERSON_REACH of the face side around the matte's edge) filled in from around (its nearest colours
 * carried in: PLATE_TRUST), the fill made at most PLATE_SIDE pixels wide and high, then enlarged. scene (H, W, 3)
 * uint8; landmarks (68, 2) its face, frame pixels; matte (H, W) float32. */
export function backgroundPlate(scene: Tensor<Uint8Array>, landmarks: Tensor, matte: Tensor<Float32Array>
                                ): { matte: Tensor<Float32Array>; plate: Tensor<Uint8Array> } {
  const [height, width] = scene.shape;
  if (matte.shape[0] !== height || matte.shape[1] !== width) {
    throw new Error(`the matte must be the scene's size [${height}, ${width}], got [${matte.shape}]`);
  }
  const clipped = Float32Array.from(matte.data, (v) => Math.min(Math.max(v, 0), 1));
  const reach = Math.max(1, roundHalfEven(PERSON_REACH * faceSide(landmarks)));
  const person = dilateEllipse(Uint8Array.from(clipped, (v) => (v > PERSON_LEVEL ? 1 : 0)), width, height, reach);
  const known = tensor(Float32Array.from(person, (v) => 1 - v), [height, width]);
  const shrink = Math.max(1, Math.max(height, width) / PLATE_SIDE);
  const smallW = Math.max(1, roundHalfEven(width / shrink)), smallH = Math.max(1, roundHalfEven(height / shrink));
  const small = resizeUint8(scene, smallW, smallH, "area");
  const filled = fillIn(tensor(Float32Array.from(small.data), [smallH, smallW, 3]),
                        resizeImage(known, smallW, smallH, "area"), PLATE_TRUST);
  const enlarged = resizeUint8(tensor(toUint8(filled.data), [smallH, smallW, 3]), width, height, "linear");
  const plate = scene.data.slice();
  for (let p = 0; p < height * width; p++) {
    if (person[p]) { plate[3 * p] = enlarged.data[3 * p]; plate[3 * p + 1] = enlarged.data[3 * p + 1]; plate[3 * p + 2] = enlarged.data[3 * p + 2]; }
  }
  return { matte: tensor(clipped, [height, width]), plate: tensor(plate, [height, width, 3]) };
}
