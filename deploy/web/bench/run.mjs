// Bundles bench/stages.ts with the library's sources (esbuild, as build.mjs bundles the page) into bench/out/ (ignored
// by git) and runs it with this command's arguments (stages.ts lists them). With --profile, node's CPU profile of the
// run is written to bench/out/profiles and its functions' self and total time printed (bench/profile.mjs).
import { build } from "esbuild";
import { spawnSync } from "node:child_process";
import { fileURLToPath } from "node:url";
import { dirname, join } from "node:path";

const here = dirname(fileURLToPath(import.meta.url));
const outfile = join(here, "out", "stages.mjs");
await build({ entryPoints: [join(here, "stages.ts")], outfile, bundle: true, format: "esm", platform: "node",
              target: "es2022", sourcemap: true, external: ["onnxruntime-web"], logLevel: "warning" });
const args = process.argv.slice(2).filter((arg) => arg !== "--profile");
const profile = process.argv.includes("--profile");
const flags = profile ? ["--enable-source-maps", "--cpu-prof", "--cpu-prof-dir", join(here, "out", "profiles")] : [];
const done = spawnSync(process.execPath, [...flags, outfile, ...args], { stdio: "inherit" });
if (profile && done.status === 0) {
  spawnSync(process.execPath, [join(here, "profile.mjs"), join(here, "out", "profiles")], { stdio: "inherit" });
}
process.exit(done.status ?? 1);
