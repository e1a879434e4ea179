// The face tracker in a worker of its own (the page's): it tracks camera frame n + 1 while the page warps the shots of
// frame n and onnxruntime's proxy worker runs frame n - 1's network. Messages: {assets} once, then {id, frame} (or
// {id, rgba, width, height}: a canvas's pixels) -> {id, points (136 float64) | null, mouth (interior.ts DriverMouth,
// cut here where the frame is) | null, eyes (eyes.ts EyePatch, likewise) | null, irises (8 float64, gaze.ts
// trackedIrises) | null} or {id, error}.

import * as ort from "onnxruntime-web";

import { cutEyePatch } from "./eyes.js";
import { trackedIrises } from "./gaze.js";
import { cutDriverMouth } from "./interior.js";
import { MeshTracker, TrackerAssets, createTracker } from "./tracker.js";
import { Tensor, tensor } from "./tensor.js";

let tracker: MeshTracker | null = null;
let spare: Uint8Array | null = null;  // an RGB buffer for RGBA frames, kept from frame to frame when free

/** RGBA pixels -> an (H, W, 3) RGB frame, in the spare buffer when it is free. */
function fromRgba(rgba: Uint8ClampedArray, width: number, height: number): Tensor<Uint8Array> {
  const size = width * height * 3;
  const rgb = spare !== null && spare.length === size ? spare : new Uint8Array(size);
  spare = null;
  for (let i = 0, j = 0; i < size; i += 3, j += 4) { rgb[i] = rgba[j]; rgb[i + 1] = rgba[j + 1]; rgb[i + 2] = rgba[j + 2]; }
  return tensor(rgb, [height, width, 3]);
}

self.onmessage = async (event: MessageEvent) => {
  const message = event.data;
  try {
    if (message.assets) {
      ort.env.wasm.wasmPaths = message.wasmPaths;
      ort.env.wasm.numThreads = 1;  // small nets: one thread each, beside the frame generator's
      tracker = await createTracker(message.assets as TrackerAssets, { irisGate: true });  // a camera stream
      self.postMessage({ ready: true });
      return;
    }
    const frame = message.rgba ? fromRgba(message.rgba, message.width, message.height) : message.frame;
    const points = await tracker!.update(frame);
    const mouth = points === null ? null : cutDriverMouth(frame, points);
    const eyes = points === null ? null : cutEyePatch(frame, points);
    const irises = points === null ? null : await trackedIrises(tracker!, frame, points);
    if (message.rgba) spare = frame.data;
    self.postMessage({ id: message.id, points: points === null ? null : points.data, mouth, eyes, irises });
  } catch (error) {
    self.postMessage({ id: message.id, error: error instanceof Error ? error.message : String(error) });
  }
};
