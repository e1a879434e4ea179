// The page (deploy/web/static/index.html): the webcam drives the example person, everything on this machine.
// Test and benchmark hooks live on `window.lsr` (tests/deploy/test_web_browser.py, lsr bench web).

import * as ort from "onnxruntime-web";

import { BACKEND_NAMES, Backend, Failure, GPU_RUNTIME, askedBackend, chooseBackends, probeBrowser } from "./backend.js";
import { Runtime, createFrameGenerator } from "./network.js";
import { RemoteTracker } from "./remote_tracker.js";
import { PersonModels, encodePerson, loadPersonModels, photoFromImageData, shrinkPhoto } from "./encode.js";
import { LiveFrame, LiveSession, Person, Site, loadSite } from "./session.js";
import { Tensor, median, tensor } from "./tensor.js";

const CAMERA = { width: { ideal: 320 }, height: { ideal: 240 } }; // as lsr app's live tab asks (app/ui.py)
const MARK = "SYNTHETIC";

interface Stats {
  grabbed: number[]; shown: number[]; latency: number[]; ms: number[]; stages: Record<string, number>[];
  // each time the page saw a camera frame, tracked or not, and the camera's frames presented by then (frames that
  // came while this thread was busy are counted, not seen): the share shown of what the camera sent
  cameraTimes: number[]; cameraFrames: number[];
  faces: number; frames: number;
}

declare global {
  interface Window { lsr: Record<string, unknown> }
}

const element = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;

/** Cross-origin isolation (for WASM threads) through sw.js on a static host that sends no headers: register it
 * and reload once. */
async function isolate(): Promise<boolean> {
  if (globalThis.crossOriginIsolated || !("serviceWorker" in navigator) || sessionStorage.getItem("lsr-isolating")) {
    return false;
  }
  await navigator.serviceWorker.register("./sw.js");
  await navigator.serviceWorker.ready;
  sessionStorage.setItem("lsr-isolating", "1");
  location.reload();
  return true;
}

/** An onnxruntime-web build's settings: the page's WASM one, and the GPU one where it is loaded. */
function configureOnnxRuntime(runtime: Runtime): void {
  runtime.env.wasm.wasmPaths = new URL("./", location.href).href;
  // The frame generator's threads: the cores beside this thread and the tracker's worker (one thread each), at
  // most 4. On 2 cores that is 1: measured there, the stages overlap best so (10.6 fps against 7.9 with 2 threads).
  // ?threads=N asks for N. More than one needs cross-origin isolation (sw.js).
  const asked = Number(new URLSearchParams(location.search).get("threads"));
  const most = globalThis.crossOriginIsolated ? Math.min(4, navigator.hardwareConcurrency || 1) : 1;
  const spare = Math.max(1, Math.min(4, (navigator.hardwareConcurrency || 1) - 2));
  runtime.env.wasm.numThreads = Math.min(asked > 0 ? asked : spare, most);
  runtime.env.wasm.proxy = true;  // the networks run in a worker: this thread tracks and warps the next frame meanwhile
}

/** Each backend's onnxruntime-web build: the page's own for WASM, the GPU one (backend.ts) for WebGPU and WebNN,
 * fetched the first time it is asked for. */
function runtimeLoader(): (backend: Backend) => Promise<Runtime> {
  let gpu: Promise<Runtime> | undefined;
  return async (backend) => {
    if (backend === "wasm") return ort;
    gpu ??= (import(/* @vite-ignore */ GPU_RUNTIME) as Promise<Runtime>).then((runtime) => {
      configureOnnxRuntime(runtime);
      return runtime;
    });
    return gpu;
  };
}

/** An RGB (H, W, 3) frame -> RGBA ImageData (into `into` when it is the frame's size). */
function toImageData(image: Tensor<Uint8Array>, into?: ImageData): ImageData {
  const [height, width] = image.shape;
  const pixels = into && into.width === width && into.height === height ? into : new ImageData(width, height);
  const rgba = pixels.data, data = image.data;
  for (let i = 0, j = 0; i < data.length; i += 3, j += 4) {
    rgba[j] = data[i]; rgba[j + 1] = data[i + 1]; rgba[j + 2] = data[i + 2]; rgba[j + 3] = 255;
  }
  return pixels;
}

/** RGBA canvas pixels -> an RGB (H, W, 3) frame. */
function fromImageData(pixels: ImageData): Tensor<Uint8Array> {
  const rgb = new Uint8Array(pixels.width * pixels.height * 3);
  for (let i = 0, j = 0; j < pixels.data.length; i += 3, j += 4) {
    rgb[i] = pixels.data[j]; rgb[i + 1] = pixels.data[j + 1]; rgb[i + 2] = pixels.data[j + 2];
  }
  return tensor(rgb, [pixels.height, pixels.width, 3]);
}

/** The provenance mark of lsr.core.provenance.draw_watermark: white text on a darkened box, bottom right. */
function drawMark(context: CanvasRenderingContext2D, width: number, height: number): void {
  const size = Math.max(10, Math.round(Math.min(width, height) / 22));
  context.font = `600 ${size}px system-ui, sans-serif`;
  const textWidth = context.measureText(MARK).width, pad = Math.max(2, Math.round(size / 3));
  context.fillStyle = "rgba(0, 0, 0, 0.6)";
  context.fillRect(width - textWidth - 3 * pad, height - size - 3 * pad, textWidth + 2 * pad, size + 2 * pad);
  context.fillStyle = "#fff";
  context.textBaseline = "bottom";
  context.fillText(MARK, width - textWidth - 2 * pad, height - 2 * pad);
}

/** The latent layout as parts (lsr.layout_view.layout_parts_rgb: each pixel's strongest channel in a fixed colour)
 * with a legend of the channels covering at least 2 % of it (the canvas sized and the legend written only when they
 * change: each costs the page a reflow). */
function drawLayout(canvas: HTMLCanvasElement, legend: HTMLElement, layout: Tensor<Float32Array>, site: Site): void {
  const [channels, height, width] = layout.shape, plane = height * width, data = layout.data;
  const palette = site.config.layout_palette, names = site.config.layout_legend;
  const rgba = new Uint8ClampedArray(plane * 4), counts = new Array(channels).fill(0);
  for (let p = 0; p < plane; p++) {
    let best = 0, strongest = data[p];
    for (let c = 1, at = plane + p; c < channels; c++, at += plane) {
      if (data[at] > strongest) { best = c; strongest = data[at]; }
    }
    counts[best] += 1;
    const colour = palette[best % palette.length];
    rgba[4 * p] = colour[0]; rgba[4 * p + 1] = colour[1]; rgba[4 * p + 2] = colour[2]; rgba[4 * p + 3] = 255;
  }
  if (canvas.width !== width || canvas.height !== height) { canvas.width = width; canvas.height = height; }
  canvas.getContext("2d")!.putImageData(new ImageData(rgba, width, height), 0, 0);
  const shown = counts.map((count, c) => [count / plane, c]).filter(([share]) => share >= 0.02)
    .sort((a, b) => b[0] - a[0]).slice(0, 6);
  const html = shown.map(([, c]) => {
    const colour = palette[c % palette.length];
    return `<div><span style="background:rgb(${colour.join(",")})"></span>${names?.[c] ?? `channel ${c}`}</div>`;
  }).join("");
  if (legend.dataset.html !== html) { legend.innerHTML = html; legend.dataset.html = html; }
}

/** An image file -> an upright (H, W, 3) RGB photo, at most 1280 pixels on its long side (the scene is composited
 * every frame at its full size). */
async function decodePhoto(file: File): Promise<Tensor<Uint8Array>> {
  const bitmap = await createImageBitmap(file, { imageOrientation: "from-image" });
  const { width, height } = bitmap;
  const context = new OffscreenCanvas(width, height).getContext("2d")!;
  context.drawImage(bitmap, 0, 0);
  bitmap.close();
  return shrinkPhoto(photoFromImageData(context.getImageData(0, 0, width, height)), 1280);
}

function base64ToBytes(text: string): Uint8Array {
  const binary = atob(text), bytes = new Uint8Array(binary.length);
  for (let i = 0; i < binary.length; i++) bytes[i] = binary.charCodeAt(i);
  return bytes;
}

function bytesToBase64(bytes: Uint8Array): string {
  let binary = "";
  for (let i = 0; i < bytes.length; i += 0x8000) binary += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(binary);
}

async function main(): Promise<void> {
  if (await isolate()) return;
  configureOnnxRuntime(ort);
  const status = element<HTMLSpanElement>("status"), statsLine = element<HTMLParagraphElement>("stats");
  const output = element<HTMLCanvasElement>("output"), layoutCanvas = element<HTMLCanvasElement>("layout");
  const video = element<HTMLVideoElement>("camera"), start = element<HTMLButtonElement>("start");
  const recentre = element<HTMLButtonElement>("recentre");
  const wasmPaths = ort.env.wasm.wasmPaths as string;
  const workers: { tracker?: RemoteTracker } = {};
  const read = async (path: string) => new Uint8Array(await (await fetch(path)).arrayBuffer());
  // the frame generator on the GPU where the browser has one (?backend=webgpu|webnn|wasm asks for one), else WASM
  const backends = chooseBackends(await probeBrowser(), askedBackend(location.search));
  let failures: Failure[] = [];
  const site = await loadSite(read,
                              async (assets) => (workers.tracker = await RemoteTracker.create("./tracker.worker.js", assets,
                                                                                               wasmPaths)),
                              async (model, sizes, latents) => {
                                const chosen = await createFrameGenerator(model, sizes, latents, backends, runtimeLoader());
                                failures = chosen.failures;
                                return chosen.value;
                              });
  const backend = site.generator.backend;
  console.info(`lsr: the frame generator runs on ${BACKEND_NAMES[backend]} (tried ${backends.join(", ")})`);
  document.body.dataset.backend = backend;
  const [height, width] = site.person.scene.shape;
  const context = output.getContext("2d")!;
  let shownPixels: ImageData | undefined;  // the canvas's pixels, the same buffer each frame
  const show = (frame: Tensor<Uint8Array>) => {
    const [frameHeight, frameWidth] = frame.shape;
    if (output.width !== frameWidth || output.height !== frameHeight) {  // another person's scene
      output.width = frameWidth; output.height = frameHeight;
      shownPixels = undefined;
    }
    shownPixels = toImageData(frame, shownPixels);
    context.putImageData(shownPixels, 0, 0);
    drawMark(context, frameWidth, frameHeight);
  };
  show(site.person.scene);
  const threads = ort.env.wasm.numThreads;
  const failed = failures.map((failure) => BACKEND_NAMES[failure.backend]);
  status.textContent = `Ready (onnxruntime-web, the network on ${BACKEND_NAMES[backend]}, ` +
    `${threads} thread${threads === 1 ? "" : "s"}${failed.length ? `; ${failed.join(" and ")} failed, see the console` : ""}). ` +
    "Start the camera to drive the person.";
  const stats: Stats = { grabbed: [], shown: [], latency: [], ms: [], stages: [], cameraTimes: [], cameraFrames: [], faces: 0, frames: 0 };
  let session = new LiveSession(site, site.config.layout !== "none");
  let running = false;

  // The tracker takes the camera's newest frame as soon as it is free, read only then: the video element holds the
  // newest frame, and `fresh` says one has come since the last read (its arrival time: where the latency starts).
  // Reading every frame as it came cost a draw and a 1.2 MB read-back for each frame the tracker then skipped.
  const grabCanvas = document.createElement("canvas");
  const grabContext = grabCanvas.getContext("2d", { willReadFrequently: true })!;
  let fresh: number | null = null;
  let arrived: (() => void) | null = null;
  /** Calls `next` at the video's next frame with the frames presented so far (null where the browser does not say). */
  const onVideoFrame = (next: (presented: number | null) => void) => {
    if ("requestVideoFrameCallback" in video) video.requestVideoFrameCallback((_, frame) => next(frame.presentedFrames));
    else requestAnimationFrame(() => next(null));
  };
  const watch = (presented: number | null = null) => {
    if (!running) return;
    if (video.videoWidth) {
      fresh = performance.now();
      stats.cameraTimes.push(fresh);
      stats.cameraFrames.push(presented ?? stats.cameraFrames.length + 1);
      arrived?.();
      arrived = null;
    }
    onVideoFrame(watch);
  };
  /** The newest camera frame's pixels, and when it came. */
  const readCamera = (grabbed: number): { pixels: ImageData; grabbed: number } => {
    if (grabCanvas.width !== video.videoWidth || grabCanvas.height !== video.videoHeight) {
      grabCanvas.width = video.videoWidth; grabCanvas.height = video.videoHeight;
    }
    grabContext.drawImage(video, 0, 0);
    return { pixels: grabContext.getImageData(0, 0, grabCanvas.width, grabCanvas.height), grabbed };
  };

  const record = (result: LiveFrame, grabbed: number) => {
    show(result.image);
    if (result.layout) drawLayout(layoutCanvas, element("legend"), result.layout, site);
    const shown = performance.now();
    stats.frames += 1;
    if (result.face) stats.faces += 1;
    stats.grabbed.push(grabbed); stats.shown.push(shown); stats.latency.push(shown - grabbed); stats.ms.push(result.ms);
    stats.stages.push(result.stages as Record<string, number>);
    let first = stats.shown.length - 1;  // the frames shown in the last 2 s: a loop back from the newest, not a
    while (first > 0 && stats.shown[first - 1] > shown - 2000) first--;  // filter over the whole stream each frame
    const last = stats.shown.length - 1;
    const fps = first < last ? (last - first) / ((shown - stats.shown[first]) / 1000) : NaN;
    statsLine.textContent = `${fps.toFixed(1)} fps · ${result.ms.toFixed(0)} ms per frame (${BACKEND_NAMES[backend]}) · latency ` +
      `${median(stats.latency.slice(-30)).toFixed(0)} ms · frame ${stats.frames}` +
      (result.face ? "" : " · no face in the camera: showing the last frame");
  };

  /** The newest camera frame not tracked yet (waiting for one if there is none) and its face. */
  const grab = async () => {
    while (fresh === null) await new Promise<void>((resolve) => { arrived = resolve; });
    const { pixels, grabbed } = readCamera(fresh);
    fresh = null;
    const tracking = performance.now();
    // the tracker's worker takes the canvas's RGBA pixels as they are (it drops the alpha)
    const face = await (workers.tracker ? workers.tracker.updateRgba(pixels) : site.tracker.update(fromImageData(pixels)));
    return { grabbed, face, track: performance.now() - tracking };
  };

  /** Frames in flight on three threads: the tracker's worker finds the face in the newest camera frame, this
   * thread retargets it and warps the shots, onnxruntime's worker runs the network of the frame before, and as soon
   * as a frame leaves the network this thread completes it (the warp-guided blend, mouth, eyes, composite) and shows
   * it, while the next frame's network runs: the network's worker, the slowest stage, never waits for the composite. Frames are shown
   * in order; a frame without a face shows the last good output when its turn comes. */
  async function loop(): Promise<void> {
    let networkFree: Promise<unknown> = Promise.resolve();  // the frame before has left the network
    let shown: Promise<void> = Promise.resolve();  // the frame before has been shown
    let tracking = grab();
    while (running) {
      const { grabbed, face, track } = await tracking;
      tracking = grab();
      const current = session;  // a person chosen meanwhile takes over from the next frame
      const prepared = current.fromFace(face, grabbed / 1000, grabbed, track);
      await networkFree;
      if ("image" in prepared) {
        shown = shown.then(() => record({ ...prepared, image: current.last?.image ?? prepared.image }, grabbed));
        continue;
      }
      const synthesized = current.synthesize(prepared);
      networkFree = synthesized;
      shown = Promise.all([synthesized, shown]).then(([frame]) => record(current.complete(frame), grabbed));
    }
    await shown;
    await tracking;
  }

  async function startCamera(): Promise<void> {
    start.disabled = true;
    try {
      video.srcObject = await navigator.mediaDevices.getUserMedia({ video: CAMERA, audio: false });
      await video.play();
    } catch (error) {
      status.textContent = `The camera did not start: ${error instanceof Error ? error.message : error}`;
      start.disabled = false;
      return;
    }
    status.textContent = "Live: your face drives the person.";
    recentre.disabled = false;
    running = true;
    watch();
    void loop();
  }

  start.disabled = false;
  start.onclick = () => void startCamera();
  recentre.onclick = () => session.recentre();

  // the person: the example one (encoded by lsr export --web), or the user's own photos encoded here
  const layout = site.config.layout !== "none";
  const photosInput = element<HTMLInputElement>("photos"), example = element<HTMLButtonElement>("example");
  let personModels: Promise<PersonModels> | null = null;
  const usePerson = (person: Person, note: string) => {
    session = new LiveSession({ ...site, person }, layout);
    if (!running) show(person.scene);
    example.disabled = person === site.person;
    status.textContent = note;
  };
  photosInput.onchange = async () => {
    const files = Array.from(photosInput.files ?? []);
    if (!files.length) return;
    status.textContent = `Encoding ${files.length} photo${files.length === 1 ? "" : "s"}…`;
    try {
      const photos = await Promise.all(files.map(decodePhoto));
      personModels ??= loadPersonModels(read);
      const person = await encodePerson(photos, await personModels, site.config);
      const shots = person.shots.shape[0], banked = person.eyeBank ? person.eyeBank.patches.shape[0] : 0;
      usePerson(person, `Your person: ${shots} shot${shots === 1 ? "" : "s"}.` +
                        (banked ? ` Its own eyes from ${banked} of them.` : "") +
                        (person.notes.length ? ` ${person.notes.join(" ")}` : ""));
    } catch (error) {
      status.textContent = `Those photos could not be used: ${error instanceof Error ? error.message : error}`;
    } finally {
      photosInput.value = "";
    }
  };
  example.onclick = () => usePerson(site.person, "The example person.");

  window.lsr = {
    site, stats, threads, backend, backends, failures, startCamera,
    /** Fresh session, frames (base64 of (T, H, W, 3) uint8) at fps -> base64 of the composited (T, H', W', 3). */
    reenactFrames: async (frames: string, shape: number[], fps: number) => {
      const fresh = new LiveSession(site, false), data = base64ToBytes(frames), size = shape[1] * shape[2] * 3;
      const out = new Uint8Array(shape[0] * width * height * 3);
      for (let t = 0; t < shape[0]; t++) {
        const frame = tensor(data.slice(t * size, (t + 1) * size), [shape[1], shape[2], 3]);
        out.set((await fresh.step(frame, t / fps)).image.data, t * width * height * 3);
      }
      return bytesToBase64(out);
    },
    resetSession: () => { session = new LiveSession(site, site.config.layout !== "none"); },
  };
  document.body.dataset.ready = "1";
  if (new URLSearchParams(location.search).has("autostart")) void startCamera();
}

main().catch((error) => {
  const status = document.getElementById("status");
  if (status) status.textContent = `Failed: ${error instanceof Error ? error.message : error}`;
  document.body.dataset.failed = String(error);
  console.error(error);
});
