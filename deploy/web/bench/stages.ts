// The page's per-frame stages timed in Node (issue 65): src/session.ts LiveSession on the shipped default's site and
// the bundled driver's first frames, frame by frame as reenactFrames (the tests' path) runs them (prepare, then
// finish), each stage's median over the frames with a face; the warps (warpReferences) and the composite
// (compositeFace) are also timed again on their own on each frame's target. A command that prints a table, not a
// test. Its inputs, once (the site as tests/deploy/conftest.py's `site` fixture writes it, the frames as its
// `driver_frames` fixture reads them, raw):
//
//   lsr export --web DIR/site
//   python -c "import json, sys, numpy as np; from landmarks.io.video import iter_frames; from lsr.examples import
//     REAL_DRIVER; f = np.stack([x for _, x in zip(range(60), iter_frames(REAL_DRIVER))]); d = sys.argv[1];
//     open(d + '/frames.u8', 'wb').write(f.tobytes()); json.dump({'shape': f.shape}, open(d + '/frames.json', 'w'))" DIR
//
//   node bench/run.mjs DIR [--repeat 3] [--javascript] [--save F] [--compare F] [--profile]
//
// --repeat: runs over the frames, each on a freshly loaded site (its tracker keeps the
// last face). --javascript: the kernels of remap_wasm.ts and tps_wasm.ts turned off (wasm.ts useWebAssembly), the
// JavaScript they stand in for instead. --save writes the first run's composited frames (T, H, W, 3) raw; --compare
// reads such a file (another build's, say the old path's) and prints the lowest PSNR and the largest difference of
// this run's frames against it. --profile (run.mjs): node's CPU profile, its functions' self and total time. The
// network runs on one WASM thread, as in the tests.

import { readFile, writeFile } from "node:fs/promises";
import * as ort from "onnxruntime-web";

import { compositeFace } from "../src/composite.js";
import { folderReader } from "../src/files.js";
import { invertAffine, transformPoints } from "../src/geometry.js";
import { warpReferences } from "../src/references.js";
import { LiveSession, Stages, loadSite } from "../src/session.js";
import { median, tensor } from "../src/tensor.js";
import { useWebAssembly } from "../src/wasm.js";

const now = () => performance.now();
const STAGES = ["track", "retarget", "warps", "network", "mouth", "composite"];
const ALONE = ["warpReferences alone", "compositeFace alone"];

function option(name: string, fallback: string | null = null): string | null {
  const at = process.argv.indexOf(name);
  return at < 0 ? fallback : process.argv[at + 1];
}

/** The PSNR in dB of two uint8 pictures (Infinity where equal) and their largest difference. */
function compare(a: Uint8Array, b: Uint8Array): [number, number] {
  let squared = 0, most = 0;
  for (let i = 0; i < a.length; i++) {
    const d = a[i] - b[i];
    squared += d * d;
    most = Math.max(most, Math.abs(d));
  }
  return [squared === 0 ? Infinity : 10 * Math.log10((255 * 255 * a.length) / squared), most];
}

async function main(): Promise<void> {
  const folder = process.argv[2];
  if (!folder || folder.startsWith("--")) {
    throw new Error("usage: node bench/run.mjs DIR [--repeat N] [--javascript] [--save F] [--compare F] [--profile]");
  }
  const repeat = Number(option("--repeat", "3"));
  useWebAssembly(!process.argv.includes("--javascript"));
  ort.env.wasm.numThreads = 1;
  const shape = JSON.parse(await readFile(`${folder}/frames.json`, "utf8")).shape as number[];
  const frames = new Uint8Array(await readFile(`${folder}/frames.u8`));
  const [count, height, width] = shape, size = height * width * 3;

  const times: Record<string, number[]> = {};
  const add = (key: string, ms: number) => (times[key] ??= []).push(ms);
  let first: Uint8Array | null = null;
  let described = "";
  for (let run = 0; run < repeat; run++) {
    const site = await loadSite(await folderReader(`${folder}/site`));
    const { config, person } = site;
    const session = new LiveSession(site, false);
    const cropToScene = invertAffine(person.sceneMatrix);
    const crop = config.crop_size * config.crop_size * 3;  // the anchor shot stands in for the finished face
    const anchorShot = tensor(person.shots.data.slice(person.anchor * crop, (person.anchor + 1) * crop),
                              [config.crop_size, config.crop_size, 3]);
    const irises = session.warpsIrises ? tensor(person.shotIrises, [person.shots.shape[0], 2, 2]) : null;
    const out = new Uint8Array(count * person.scene.data.length);
    described = `${count} frames x ${repeat} runs, scene ${person.scene.shape.slice(0, 2).join("x")}, crop `
      + `${config.crop_size}, ${config.references} references of ${person.shots.shape[0]} shots, `
      + (process.argv.includes("--javascript") ? "JavaScript kernels" : "WebAssembly kernels where they run");
    for (let t = 0; t < count; t++) {
      const frame = tensor(frames.slice(t * size, (t + 1) * size), [height, width, 3]);
      const prepared = await session.prepare(frame, t / 25);
      const result = "image" in prepared ? prepared : await session.finish(prepared);
      out.set(result.image.data, t * result.image.data.length);
      if (!result.face || result.target === null) continue;
      for (const [key, ms] of Object.entries(result.stages as Stages)) add(key, ms);
      add("total", Object.values(result.stages).reduce((a, b) => a + (b ?? 0), 0));
      let started = now();
      warpReferences(person.shots, person.shotLandmarks, result.target, config.references, 4, irises, null);
      add(ALONE[0], now() - started);
      started = now();
      compositeFace(person.scene, person.sceneLandmarks, transformPoints(result.target, cropToScene), anchorShot,
                    person.sceneMatrix, person.layers);
      add(ALONE[1], now() - started);
    }
    first ??= out;
  }
  console.log(described);
  console.log("stage                        median ms   p90 ms");
  for (const key of [...STAGES, "total", ...ALONE]) {
    const values = times[key];
    if (!values) continue;
    const sorted = [...values].sort((a, b) => a - b);
    console.log(`${key.padEnd(28)} ${median(values).toFixed(2).padStart(9)} ${sorted[Math.floor(0.9 * (sorted.length - 1))].toFixed(2).padStart(8)}`);
  }
  const save = option("--save");
  if (save && first) await writeFile(save, first);
  const against = option("--compare");
  if (against && first) {
    const old = new Uint8Array(await readFile(against)), frameSize = first.length / count;
    let lowest = Infinity, most = 0;
    for (let t = 0; t < count; t++) {
      const [db, largest] = compare(old.subarray(t * frameSize, (t + 1) * frameSize), first.subarray(t * frameSize, (t + 1) * frameSize));
      lowest = Math.min(lowest, db);
      most = Math.max(most, largest);
    }
    console.log(`against ${against}: lowest PSNR ${lowest === Infinity ? "inf (bit-identical)" : `${lowest.toFixed(2)} dB`}, `
                + `largest difference ${most}`);
  }
}

await main();
