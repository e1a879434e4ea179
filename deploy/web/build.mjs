// Bundles the web runtime: dist/app.js (the page, for browsers) and dist/lsr.node.mjs (the same library for Node,
// which the Python tests call through src/bridge.ts to compare each step with its Python reference).
import { build } from "esbuild";

const common = { bundle: true, sourcemap: true, target: "es2022", logLevel: "warning" };
await build({ ...common, entryPoints: ["src/app.ts"], outfile: "dist/app.js", format: "esm", platform: "browser",
              external: ["onnxruntime-web"] });
await build({ ...common, entryPoints: ["src/bridge.ts"], outfile: "dist/lsr.node.mjs", format: "esm", platform: "node",
              external: ["onnxruntime-web"] });
