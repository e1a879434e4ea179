import * as ort from "onnxruntime-web";
import { readFileSync } from "node:fs";
ort.env.wasm.numThreads = 1;
const model = readFileSync(process.argv[2]);
const profile = process.argv[3] === "profile";
const s = await ort.InferenceSession.create(model, { executionProviders: ["wasm"], graphOptimizationLevel: "all", enableProfiling: profile });
const feeds = {};
let seed = 1; const rnd = () => ((seed = (seed * 1103515245 + 12345) >>> 0) / 2 ** 32);
for (const m of s.inputMetadata) {
  const shape = m.shape.map((d) => (typeof d === "number" ? d : 1));
  const n = shape.reduce((a, b) => a * b, 1);
  const data = new Float32Array(n); for (let i = 0; i < n; i++) data[i] = rnd() * 2 - 1;
  if (m.name === "reference_masks") data.fill(1);
  feeds[m.name] = new ort.Tensor("float32", data, shape);
}
const times = [];
for (let i = 0; i < 25; i++) { const t = performance.now(); await s.run(feeds); times.push(performance.now() - t); }
times.sort((a, b) => a - b);
console.log("median ms", times[12].toFixed(1));
if (profile) s.endProfiling();
