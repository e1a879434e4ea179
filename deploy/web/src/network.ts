// The frame generator (frame_generator.onnx, `lsr export`) on onnxruntime-web: deploy/runtime.py OnnxBackend.synthesize
// with the picture conversions of lsr/core/images.py (to_network, from_network). deploy/README.md lists its I/O.
// Every input is a fresh array: with onnxruntime-web's proxy worker (the page's), inputs are handed over to it.

import * as ort from "onnxruntime-web";

import { Tensor, tensor } from "./tensor.js";

export interface Latents { layout: Float32Array; style: Float32Array }

/** Each uint8 value's float32 in [-1, 1], v / 127.5 - 1 (as to_network computes it, then rounded to float32). */
const NETWORK_VALUES = Float32Array.from({ length: 256 }, (_, v) => v / 127.5 - 1);

/** (..., H, W, 3) uint8 pictures -> (..., 3, H, W) float32 in [-1, 1] (lsr.core.images.to_network), into `out`. */
export function toNetwork(images: ArrayLike<number>, count: number, side: number,
                          out: Float32Array<ArrayBuffer> = new Float32Array(count * 3 * side * side)): Float32Array<ArrayBuffer> {
  const plane = side * side, values = NETWORK_VALUES;
  if (!(images instanceof Uint8Array || images instanceof Uint8ClampedArray)) {  // any numbers: computed each
    for (let i = 0; i < count * plane * 3; i++) {
      const n = Math.floor(i / (plane * 3)), p = Math.floor((i % (plane * 3)) / 3), c = i % 3;
      out[n * plane * 3 + c * plane + p] = images[i] / 127.5 - 1;
    }
    return out;
  }
  for (let n = 0; n < count; n++) {
    const base = n * plane * 3;
    for (let p = 0, pixel = base; p < plane; p++, pixel += 3) {
      out[base + p] = values[images[pixel]];
      out[base + plane + p] = values[images[pixel + 1]];
      out[base + 2 * plane + p] = values[images[pixel + 2]];
    }
  }
  return out;
}

/** (3, H, W) float in [-1, 1] -> (H, W, 3) uint8, rounded half to even as numpy's rint (lsr.core.images.from_network;
 * the clamped view's store rounds half to even and saturates). */
export function fromNetwork(image: Float32Array, side: number): Tensor<Uint8Array> {
  const plane = side * side, out = new Uint8Array(plane * 3);
  const clamped = new Uint8ClampedArray(out.buffer);
  for (let c = 0; c < 3; c++) {
    for (let p = 0, i = c * plane; p < plane; p++, i++) clamped[3 * p + c] = (image[i] + 1) * 127.5;
  }
  return tensor(out, [side, side, 3]);
}

export interface Synthesis { image: Tensor<Uint8Array>; layout: Tensor<Float32Array> | null }

/** The frame graph: landmark image (S, S, 3) uint8, latents, and for a warp-guided model the N warped references
 * (N, C, C, 3) uint8 with their masks (N, C, C) in {0, 1} -> the (C, C, 3) face [and the (C_l, S, S) layout]. */
export class FrameGenerator {
  readonly resolution: number;
  readonly cropSize: number;
  readonly references: number;
  readonly hasLayout: boolean;

  private constructor(readonly session: ort.InferenceSession, metadata: { resolution: number; cropSize: number; references: number }) {
    this.resolution = metadata.resolution;
    this.cropSize = metadata.cropSize;
    this.references = metadata.references;
    this.hasLayout = session.outputNames.includes("layout");
  }

  /** model: frame_generator.onnx's bytes (or a URL/path onnxruntime-web can fetch); metadata: its sizes (site.json). */
  static async create(model: Uint8Array | string, metadata: { resolution: number; cropSize: number; references: number },
                      options: ort.InferenceSession.SessionOptions = {}): Promise<FrameGenerator> {
    const session = await ort.InferenceSession.create(model as Uint8Array, { graphOptimizationLevel: "all", ...options });
    return new FrameGenerator(session, metadata);
  }

  async run(landmarkImage: Tensor, latents: Latents, references?: Tensor, masks?: Tensor,
            withLayout = false): Promise<Synthesis> {
    const s = this.resolution, c = this.cropSize;
    const feed: Record<string, ort.Tensor> = {
      landmark_image: new ort.Tensor("float32", toNetwork(landmarkImage.data as Uint8Array, 1, s), [1, 3, s, s]),
      layout_latent: new ort.Tensor("float32", latents.layout.slice(), [1, latents.layout.length]),
      style_latent: new ort.Tensor("float32", latents.style.slice(), [1, latents.style.length]),
    };
    if (this.references > 0) {
      if (!references || !masks) throw new Error("a warp-guided frame generator needs the warped references and masks");
      const n = this.references;
      feed.references = new ort.Tensor("float32", toNetwork(references.data as Uint8Array, n, c), [1, n, 3, c, c]);
      feed.reference_masks = new ort.Tensor("float32", Float32Array.from(masks.data as ArrayLike<number>), [1, n, 1, c, c]);
    }
    const wanted = withLayout && this.hasLayout ? ["image", "layout"] : ["image"];
    const outputs = await this.session.run(feed, wanted);
    const image = fromNetwork(outputs.image.data as Float32Array, c);
    const layout = outputs.layout ? tensor(new Float32Array(outputs.layout.data as Float32Array), outputs.layout.dims.slice(1) as number[]) : null;
    return { image, layout };
  }
}
