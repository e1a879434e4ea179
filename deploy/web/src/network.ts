// The frame generator (frame_generator.onnx, `lsr export`) on onnxruntime-web: deploy/runtime.py OnnxBackend.synthesize
// with the picture conversions of lsr/core/images.py (to_network, from_network). deploy/README.md lists its I/O.
// Every input is a fresh array: with onnxruntime-web's proxy worker (the page's), inputs are handed over to it.

import * as ort from "onnxruntime-web";

import { Backend, OnBackend, askedBackend, chooseBackends, onFirstBackend, probeBrowser } from "./backend.js";
import { PageComposite } from "./blend_wasm.js";
import { folderReader } from "./files.js";
import { Tensor, tensor } from "./tensor.js";

/** An onnxruntime-web module: the page's WASM build, or the GPU one (backend.ts GPU_RUNTIME). */
export type Runtime = typeof ort;

/** The frame generator's sizes (site.json): its network's side S, its crop's side C, its N references, and where
 * its graph ends at G^s (output "network"), the detail split of the composite the page runs (blend_wasm.ts). */
export interface GeneratorSizes { resolution: number; cropSize: number; references: number; detailSigma?: number | null }

/** site.json's sizes of the frame generator. */
export function generatorSizes(config: { resolution: number; crop_size: number; references: number;
                                         detail_sigma?: number | null }): GeneratorSizes {
  return { resolution: config.resolution, cropSize: config.crop_size, references: config.references,
           detailSigma: config.detail_sigma ?? null };
}

/** The most grey levels a GPU backend's check frame may be from WASM's: fp32 sums in another order move a pixel by
 * one level at most (the JSEP build on Chromium's software WebGPU); the miscomputing build (backend.ts), by 123. */
export const AGREEMENT = 3;

export interface Latents { layout: Float32Array; style: Float32Array }

/** Each uint8 value's float32 in [-1, 1] as lsr.core.images.to_network computes it in float32: v / 127.5, then - 1,
 * each rounded to float32. */
const NETWORK_VALUES = Float32Array.from({ length: 256 }, (_, v) => Math.fround(v / 127.5) - 1);

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

/** A frame out of onnxruntime (FrameGenerator.runNetwork): `finish()` gives its synthesis (on a graph ending at G^s,
 * composited here then; the same result on later calls). */
export interface PendingSynthesis { finish(): Synthesis }

/** The frame graph: landmark image (S, S, 3) uint8, latents, and for a warp-guided model the N warped references
 * (N, C, C, 3) uint8 with their masks (N, C, C) in {0, 1} -> the (C, C, 3) face [and the (C_l, S, S) layout]. */
export class FrameGenerator {
  readonly resolution: number;
  readonly cropSize: number;
  readonly references: number;
  readonly hasLayout: boolean;

  private turn = 0;  // which of the two composites the next run takes
  private readonly unfinished: (Promise<void> | null)[] = [null, null];  // each composite's frame not finished yet

  /** composites: none for a graph that composites itself; else two, taken in turn, so that the next frame's network
   * runs while this frame is composited. */
  private constructor(readonly session: ort.InferenceSession, sizes: GeneratorSizes, readonly backend: Backend,
                      private readonly runtime: Runtime, private readonly composites: PageComposite[]) {
    this.resolution = sizes.resolution;
    this.cropSize = sizes.cropSize;
    this.references = sizes.references;
    this.hasLayout = session.outputNames.includes("layout");
  }

  /** model: frame_generator.onnx's bytes (handed over to onnxruntime's proxy worker where there is one: pass a copy
   * to keep them); sizes: site.json's; backend: the execution provider, of `runtime`'s onnxruntime-web build. */
  static async create(model: Uint8Array, sizes: GeneratorSizes, backend: Backend = "wasm",
                      runtime: Runtime = ort): Promise<FrameGenerator> {
    const session = await runtime.InferenceSession.create(model, { executionProviders: [backend],
                                                                   graphOptimizationLevel: "all" });
    const composites: PageComposite[] = [];
    if (session.outputNames.includes("network")) {  // the graph ends at G^s: the composite runs here
      for (let k = 0; k < 2; k++) {
        const composite = PageComposite.create(sizes.references, sizes.cropSize, sizes.resolution, sizes.detailSigma ?? NaN);
        if (composite === null) {
          await session.release();
          throw new Error(`this frame generator's composite (${sizes.references} references, detail_sigma `
                          + `${sizes.detailSigma}) needs WebAssembly SIMD and 1, 3 or 5 references`);
        }
        composites.push(composite);
      }
    }
    return new FrameGenerator(session, sizes, backend, runtime, composites);
  }

  release(): Promise<void> {
    return this.session.release();
  }

  async run(landmarkImage: Tensor, latents: Latents, references?: Tensor, masks?: Tensor,
            withLayout = false): Promise<Synthesis> {
    return (await this.runNetwork(landmarkImage, latents, references, masks, withLayout)).finish();
  }

  /** `run` up to onnxruntime's outputs: the next frame's network may start as soon as this resolves, before
   * `finish()` composites this one (at most two frames between the two). */
  async runNetwork(landmarkImage: Tensor, latents: Latents, references?: Tensor, masks?: Tensor,
                   withLayout = false): Promise<PendingSynthesis> {
    const c = this.cropSize, slot = this.turn;
    let composite: PageComposite | null = null, finished = () => {};
    if (this.composites.length > 0) {  // this frame's composite, once the frame that had it is finished
      this.turn = 1 - slot;
      while (this.unfinished[slot] !== null) await this.unfinished[slot];
      composite = this.composites[slot];
      this.unfinished[slot] = new Promise<void>((resolve) => {
        finished = () => { this.unfinished[slot] = null; resolve(); };
      });
    }
    const first = composite ? "network" : "image";
    let outputs: ort.InferenceSession.OnnxValueMapType;
    try {  // whatever fails frees the composite for the next frame
      const feed = this.feed(landmarkImage, latents, references, masks, composite);
      outputs = await this.session.run(feed, withLayout && this.hasLayout ? [first, "layout"] : [first]);
    } catch (error) {
      finished();
      throw error;
    }
    const layout = outputs.layout ? tensor(new Float32Array(outputs.layout.data as Float32Array), outputs.layout.dims.slice(1) as number[]) : null;
    const values = outputs[first].data as Float32Array;
    let synthesis: Synthesis | null = null;
    return {
      finish: () => {
        if (synthesis === null) {
          try {
            synthesis = { image: fromNetwork(composite ? composite.compose(values) : values, c), layout };
          } finally {
            finished();
          }
        }
        return synthesis;
      },
    };
  }

  /** The graph's inputs for one frame; with `composite`, the references and masks written into it, the network
   * given them pooled to its side. */
  private feed(landmarkImage: Tensor, latents: Latents, references: Tensor | undefined, masks: Tensor | undefined,
               composite: PageComposite | null): Record<string, ort.Tensor> {
    const s = this.resolution, c = this.cropSize;
    const OrtTensor = this.runtime.Tensor;  // a session takes its own build's tensors
    const feed: Record<string, ort.Tensor> = {
      landmark_image: new OrtTensor("float32", toNetwork(landmarkImage.data as Uint8Array, 1, s), [1, 3, s, s]),
      layout_latent: new OrtTensor("float32", latents.layout.slice(), [1, latents.layout.length]),
      style_latent: new OrtTensor("float32", latents.style.slice(), [1, latents.style.length]),
    };
    if (this.references === 0) return feed;
    if (!references || !masks) throw new Error("a warp-guided frame generator needs the warped references and masks");
    const n = this.references;
    if (references.data.length !== n * c * c * 3 || masks.data.length !== n * c * c) {
      throw new Error(`the references must be (${n}, ${c}, ${c}, 3) and their masks (${n}, ${c}, ${c})`);
    }
    if (composite) {  // the references into the composite's memory; the network takes them pooled to its side
      composite.loadReferences(references.data as Uint8Array, masks.data as ArrayLike<number>);
      const pooled = composite.pooled();
      feed.references = new OrtTensor("float32", pooled.references as Float32Array<ArrayBuffer>, [1, n, 3, s, s]);
      feed.reference_masks = new OrtTensor("float32", pooled.masks as Float32Array<ArrayBuffer>, [1, n, 1, s, s]);
    } else {
      feed.references = new OrtTensor("float32", toNetwork(references.data as Uint8Array, n, c), [1, n, 3, c, c]);
      feed.reference_masks = new OrtTensor("float32", Float32Array.from(masks.data as ArrayLike<number>), [1, n, 1, c, c]);
    }
    return feed;
  }
}

/** `count` seeded pseudo-random bytes (Park and Miller's minimal standard generator): the check frame's pictures. */
function noise(count: number, seed: number): Uint8Array {
  const out = new Uint8Array(count);
  for (let i = 0; i < count; i++) {
    seed = (seed * 16807) % 2147483647;
    out[i] = seed & 255;
  }
  return out;
}

/** How far apart (the most grey levels) two frame generators of the same graph draw the check frame: a landmark
 * image of noise and, for a warp-guided graph, references of noise under full masks, at `latents`. */
export async function checkFrameDifference(first: FrameGenerator, second: FrameGenerator,
                                           latents: Latents): Promise<number> {
  const s = first.resolution, c = first.cropSize, n = first.references;
  const draw = (generator: FrameGenerator) => generator.run(
    tensor(noise(s * s * 3, 1), [s, s, 3]), latents,
    n > 0 ? tensor(noise(n * c * c * 3, 2), [n, c, c, 3]) : undefined,
    n > 0 ? tensor(new Uint8Array(n * c * c).fill(1), [n, c, c]) : undefined);
  const a = (await draw(first)).image.data, b = (await draw(second)).image.data;
  let most = 0;
  for (let i = 0; i < a.length; i++) most = Math.max(most, Math.abs(a[i] - b[i]));
  return most;
}

/** The frame generator on the first of `backends` (backend.ts chooseBackends) where it works: it is created there
 * and, on a GPU backend, draws the check frame within AGREEMENT grey levels of WASM (a GPU build can compute wrongly
 * without failing). runtimeOf: each backend's onnxruntime-web build; log: where each failure's reason goes. */
export async function createFrameGenerator(model: Uint8Array, sizes: GeneratorSizes, latents: Latents,
                                           backends: readonly Backend[],
                                           runtimeOf: (backend: Backend) => Promise<Runtime> = async () => ort,
                                           log?: (message: string) => void): Promise<OnBackend<FrameGenerator>> {
  let onWasm: Promise<FrameGenerator> | undefined;  // made once: the checks' reference, and the last resort
  const wasm = () => (onWasm ??= runtimeOf("wasm").then((runtime) => FrameGenerator.create(model.slice(), sizes,
                                                                                            "wasm", runtime)));
  const chosen = await onFirstBackend(backends, async (backend) => {
    if (backend === "wasm") return wasm();
    const generator = await FrameGenerator.create(model.slice(), sizes, backend, await runtimeOf(backend));
    const apart = await checkFrameDifference(generator, await wasm(), latents);
    if (apart > AGREEMENT) {
      await generator.release();
      throw new Error(`its check frame is ${apart} grey levels from WASM's (at most ${AGREEMENT})`);
    }
    return generator;
  }, log);
  if (chosen.backend !== "wasm" && onWasm !== undefined) await (await onWasm).release();
  return chosen;
}

/** Node, for the tests: a stand-in GPU build, WASM with every output pixel moved by `skew` (a GPU that computes
 * wrongly without failing). */
function skewedRuntime(skew: number): Runtime {
  const create = async (model: Uint8Array, options: ort.InferenceSession.SessionOptions) => {
    const session = await ort.InferenceSession.create(model, { ...options, executionProviders: ["wasm"] });
    const run = session.run.bind(session);
    Object.assign(session, {
      run: async (...args: Parameters<typeof run>) => {
        const outputs = await run(...args);
        const image = (outputs.image ?? outputs.network).data as Float32Array;  // a network graph's: all its planes
        for (let i = 0; i < image.length; i++) image[i] += skew;
        return outputs;
      },
    });
    return session;
  };
  return { ...ort, InferenceSession: { ...ort.InferenceSession, create } } as unknown as Runtime;
}

/** Node, for the tests: a site's reader, its frame generator's sizes and its person's latents (one WASM thread). */
async function siteGeneratorParts(siteFolder: string) {
  const read = await folderReader(siteFolder);
  const config = JSON.parse(new TextDecoder().decode(await read("site.json")));
  const subject = JSON.parse(new TextDecoder().decode(await read("person/subject.json")));
  const latents = { layout: Float32Array.from(subject.layout_latent), style: Float32Array.from(subject.style_latent) };
  ort.env.wasm.numThreads = 1;
  return { read, sizes: generatorSizes(config), latents };
}

/** Node, for the tests: the site's frame generator made as the page makes it, in a browser stand-in with
 * `browser.gpu` (giving an adapter) and `browser.ml` (giving a context) and `?backend=asked` -> the backends chosen,
 * the one it runs on, the failures logged and its check frame's difference from WASM's. In Node onnxruntime-web has
 * WASM only, so the GPU backends fail, unless `skew` is given: then they run on skewedRuntime. */
export async function frameGeneratorInBrowser(siteFolder: string, browser: { gpu: boolean; ml: boolean },
                                              asked: string | null, skew: number | null = null) {
  const { read, sizes, latents } = await siteGeneratorParts(siteFolder);
  const standIn = { gpu: browser.gpu ? { requestAdapter: async () => ({}) } : undefined,
                    ml: browser.ml ? { createContext: async () => ({}) } : undefined };
  const backends = chooseBackends(await probeBrowser(standIn), askedBackend(asked === null ? "" : `?backend=${asked}`));
  const logged: string[] = [];
  const runtimeOf = async (backend: Backend) => (backend === "wasm" || skew === null ? ort : skewedRuntime(skew));
  const chosen = await createFrameGenerator(await read("models/frame_generator.onnx"), sizes, latents, backends,
                                            runtimeOf, (message) => logged.push(message));
  const onWasm = await FrameGenerator.create(await read("models/frame_generator.onnx"), sizes);
  const difference = await checkFrameDifference(chosen.value, onWasm, latents);
  return { backends, backend: chosen.backend, failures: chosen.failures, logged, difference };
}

/** Node, for the tests: the most grey levels apart that two frame graphs of one model draw the check frame
 * (checkFrameDifference) in the site `siteFolder` (its sizes and person's latents): a whole graph (`first`, e.g. the
 * bundle's frame_generator.onnx) against one ending at G^s whose blend the page runs (`second`, the site's). */
export async function frameGraphsDifference(siteFolder: string, first: string, second: string): Promise<number> {
  const { sizes, latents } = await siteGeneratorParts(siteFolder), file = await folderReader("/");
  const whole = await FrameGenerator.create(await file(first), sizes);
  const network = await FrameGenerator.create(await file(second), sizes);
  return checkFrameDifference(whole, network, latents);
}

/** Node, for the tests: the site's frame generator given references of the wrong size (its error message), then the
 * check frame twice: a failed frame must leave the generator's composites free for the frames after it. */
export async function generatorAfterABadFrame(siteFolder: string): Promise<{ message: string; drawn: number }> {
  const { read, sizes, latents } = await siteGeneratorParts(siteFolder);
  const generator = await FrameGenerator.create(await read("models/frame_generator.onnx"), sizes);
  const s = generator.resolution, n = generator.references, c = generator.cropSize;
  let message = "";
  for (let attempt = 0; attempt < 2; attempt++) {  // both composites in turn
    try {
      await generator.run(tensor(new Uint8Array(s * s * 3), [s, s, 3]), latents, tensor(new Uint8Array(3), [1, 1, 1, 3]),
                          tensor(new Float32Array(n * c * c), [n, c, c]));
    } catch (error) {
      message = error instanceof Error ? error.message : String(error);
    }
  }
  const first = await checkFrameDifference(generator, generator, latents);
  const second = await checkFrameDifference(generator, generator, latents);
  return { message, drawn: first + second };
}
