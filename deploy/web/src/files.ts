// Reading files in Node (tests, benchmarks) without putting node:fs into the browser bundle: the module name is a
// run-time value, so esbuild leaves the import alone.

const FS_MODULE = "node:fs/promises";

/** A reader of the files under `folder` (Node only): path -> bytes. */
export async function folderReader(folder: string): Promise<(path: string) => Promise<Uint8Array>> {
  const fs = (await import(/* @vite-ignore */ FS_MODULE)) as typeof import("node:fs/promises");
  return async (path: string) => new Uint8Array(await fs.readFile(`${folder}/${path}`));
}
