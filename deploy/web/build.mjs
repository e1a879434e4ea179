// Bundles the web runtime: dist/app.js (the page) and dist/tracker.worker.js (its face tracker's worker), for browsers,
// and dist/lsr.node.mjs (the same library for Node, which the Python tests call through src/bridge.ts to compare each
// step with its Python reference).
import { build } from "esbuild";

const common = { bundle: true, sourcemap: true, target: "es2022", logLevel: "warning" };
await build({ ...common, entryPoints: ["src/app.ts"], outfile: "dist/app.js", format: "esm", platform: "browser",
              external: ["onnxruntime-web"] });
// a worker has no import map: onnxruntime-web is the module beside it
await build({ ...common, entryPoints: ["src/tracker_worker.ts"], outfile: "dist/tracker.worker.js", format: "esm",
              platform: "browser", alias: { "onnxruntime-web": "./ort.wasm.min.mjs" }, external: ["./ort.wasm.min.mjs"] });
await build({ ...common, entryPoints: ["src/bridge.ts"], outfile: "dist/lsr.node.mjs", format: "esm", platform: "node",
              external: ["onnxruntime-web"] });
