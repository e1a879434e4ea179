// The face tracker in a worker of its own (the page's): it tracks camera frame n + 1 while the page warps the shots of
// frame n and onnxruntime's proxy worker runs frame n - 1's network. Messages: {assets} once, then {id, frame} ->
// {id, points (136 float64) | null} or {id, error}.

import * as ort from "onnxruntime-web";

import { MeshTracker, TrackerAssets, createTracker } from "./tracker.js";

let tracker: MeshTracker | null = null;

self.onmessage = async (event: MessageEvent) => {
  const message = event.data;
  try {
    if (message.assets) {
      ort.env.wasm.wasmPaths = message.wasmPaths;
      ort.env.wasm.numThreads = 1;  // small nets: one thread each, beside the frame generator's
      tracker = await createTracker(message.assets as TrackerAssets);
      self.postMessage({ ready: true });
      return;
    }
    const points = await tracker!.update(message.frame);
    self.postMessage({ id: message.id, points: points === null ? null : points.data });
  } catch (error) {
    self.postMessage({ id: message.id, error: error instanceof Error ? error.message : String(error) });
  }
};
