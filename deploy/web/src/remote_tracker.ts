// The page's side of src/tracker_worker.ts: the tracker's `update` as a message round trip.

import type { EyePatch } from "./eyes.js";
import type { DriverMouth } from "./interior.js";
import type { Face } from "./session.js";
import { TrackerAssets } from "./tracker.js";
import { Tensor, tensor } from "./tensor.js";

export class RemoteTracker {
  private next = 0;
  private readonly waiting = new Map<number, { resolve: (face: Face | null) => void; reject: (error: Error) => void }>();

  private constructor(private readonly worker: Worker) {
    worker.onmessage = (event: MessageEvent) => {
      const { id, points, mouth, eyes, irises, error } = event.data;
      const pending = this.waiting.get(id);
      if (!pending) return;
      this.waiting.delete(id);
      if (error !== undefined) pending.reject(new Error(`the tracker failed: ${error}`));
      else pending.resolve(points === null ? null : { points: tensor(points as Float64Array, [68, 2]),
                                                      mouth: mouth as DriverMouth | null,
                                                      eyes: eyes as EyePatch | null,
                                                      irises: irises as Float64Array | null });
    };
  }

  /** Start the worker (the script `url`, an ES module) and hand it the tracker's assets. */
  static async create(url: string, assets: TrackerAssets, wasmPaths: string): Promise<RemoteTracker> {
    const worker = new Worker(url, { type: "module" });
    await new Promise<void>((resolve, reject) => {
      worker.onmessage = (event: MessageEvent) => (event.data.ready ? resolve() : reject(new Error(event.data.error)));
      worker.onerror = (event) => reject(new Error(`the tracker worker did not start: ${event.message}`));
      worker.postMessage({ assets, wasmPaths });
    });
    return new RemoteTracker(worker);
  }

  /** An (H, W, 3) RGB frame (handed over to the worker) -> its face (68 points, open mouth, eyes, irises), or
   * null. */
  update(frame: Tensor<Uint8Array>): Promise<Face | null> {
    return this.send({ frame }, frame.data.buffer as ArrayBuffer);
  }

  /** `update` of a canvas's RGBA pixels as they are (handed over): the worker drops the alpha, off this thread. */
  updateRgba(pixels: ImageData): Promise<Face | null> {
    return this.send({ rgba: pixels.data, width: pixels.width, height: pixels.height }, pixels.data.buffer as ArrayBuffer);
  }

  private send(message: Record<string, unknown>, buffer: ArrayBuffer): Promise<Face | null> {
    const id = this.next++;
    return new Promise((resolve, reject) => {
      this.waiting.set(id, { resolve, reject });
      this.worker.postMessage({ id, ...message }, [buffer]);
    });
  }
}
