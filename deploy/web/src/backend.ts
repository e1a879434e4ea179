// Where the frame generator runs (issue 65: use the hardware where it exists): onnxruntime-web's WebGPU or WebNN
// execution provider where the browser has them, WASM otherwise and whenever they fail. The tracker's and the photo
// encoder's small nets stay on WASM (tracker.ts, encode.ts, segment.ts).
//
// The GPU path loads a second onnxruntime-web build, only where it is chosen: the JSEP one (`onnxruntime-web`'s
// default build, its WebGPU kernels in JavaScript; 28 MB of WASM beside the page's 14 MB). The lighter builds of
// onnxruntime-web 1.30 with its native WebGPU EP ("onnxruntime-web/webgpu", 27 MB; "/jspi", 17 MB) miscompute a
// convolution whose input channels are a multiple of 3 but not of 4 (the frame graph's 42-channel SPADE projections):
// on noise inputs the face came out 30 dB from WASM's, where the JSEP build's is within 2e-6. network.ts checks any
// GPU session against WASM on one frame before using it.

/** An execution provider of the frame generator, as onnxruntime-web names it. */
export type Backend = "webgpu" | "webnn" | "wasm";

/** Every backend, the preferred first: WASM, the fallback, is last. */
export const BACKENDS: readonly Backend[] = ["webgpu", "webnn", "wasm"];

/** How the page names each backend to the user. */
export const BACKEND_NAMES: Record<Backend, string> = { webgpu: "WebGPU", webnn: "WebNN", wasm: "WASM" };

/** The onnxruntime-web module of the GPU backends, beside app.js (deploy/web_build.py onnxruntime_files copies it). */
export const GPU_RUNTIME = "./ort.min.mjs";

/** What the browser offers besides WASM (probeBrowser). */
export interface Accelerators { webgpu: boolean; webnn: boolean }

/** The part of `navigator` the probe reads (WebGPU's and WebNN's types are not in TypeScript's DOM library). */
export interface NavigatorLike {
  gpu?: { requestAdapter(): Promise<unknown | null> };
  ml?: { createContext(): Promise<unknown> };
}

/** `?backend=webgpu|webnn|wasm` of a page's query string -> that backend, or null (none asked; another value is
 * ignored with a warning). */
export function askedBackend(search: string): Backend | null {
  const asked = new URLSearchParams(search).get("backend");
  if (asked === null || asked === "") return null;
  if ((BACKENDS as readonly string[]).includes(asked)) return asked as Backend;
  console.warn(`lsr: ?backend=${asked} is not one of ${BACKENDS.join(", ")}: ignored`);
  return null;
}

/** The backends to try, in order, always ending in "wasm": the one asked first (tried even where the probe found
 * nothing: its failure is logged), then WebGPU and WebNN where the browser has them. Asking for "wasm" gives WASM
 * alone. */
export function chooseBackends(has: Accelerators, asked: Backend | null = null): Backend[] {
  if (asked === "wasm") return ["wasm"];
  const found = BACKENDS.filter((backend) => backend !== "wasm" && has[backend as "webgpu" | "webnn"]);
  const first = asked === null ? [] : [asked];
  return [...first, ...found.filter((backend) => backend !== asked), "wasm"];
}

/** What this browser offers: WebGPU where `navigator.gpu` gives an adapter (headless Chromium has the API but no
 * adapter), WebNN where `navigator.ml` makes a context (Chromium behind its flag has the API on platforms it does not
 * support). */
export async function probeBrowser(browser: NavigatorLike | undefined = globalThis.navigator as NavigatorLike | undefined
                                   ): Promise<Accelerators> {
  const succeeds = async (attempt: (() => Promise<unknown>) | undefined) => {
    if (attempt === undefined) return false;
    try {
      return (await attempt()) != null;
    } catch {
      return false;
    }
  };
  const gpu = browser?.gpu, ml = browser?.ml;
  const [webgpu, webnn] = await Promise.all([succeeds(gpu && (() => gpu.requestAdapter())),
                                             succeeds(ml && (() => ml.createContext()))]);
  return { webgpu, webnn };
}

/** A backend that failed, and why (its error's message). */
export interface Failure { backend: Backend; reason: string }

/** What onFirstBackend made, on which backend, and the ones that failed before it. */
export interface OnBackend<T> { value: T; backend: Backend; failures: Failure[] }

/** `create` on each backend in turn until one succeeds; each failure is logged (`log`) with its reason, and the last
 * one throws with every reason. */
export async function onFirstBackend<T>(backends: readonly Backend[], create: (backend: Backend) => Promise<T>,
                                        log: (message: string) => void = console.warn): Promise<OnBackend<T>> {
  const failures: Failure[] = [];
  for (const [index, backend] of backends.entries()) {
    try {
      return { value: await create(backend), backend, failures };
    } catch (error) {
      const reason = error instanceof Error ? error.message : String(error);
      failures.push({ backend, reason });
      const next = backends[index + 1];
      log(`lsr: the frame generator could not run on ${BACKEND_NAMES[backend]} (${reason})` +
          (next === undefined ? "" : `; trying ${BACKEND_NAMES[next]}`));
    }
  }
  throw new Error(`the frame generator runs on none of ${backends.join(", ")}: ` +
                  failures.map(({ backend, reason }) => `${backend}: ${reason}`).join("; "));
}
