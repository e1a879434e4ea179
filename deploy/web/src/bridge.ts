// Node entry for the Python tests: one JSON request on stdin, {"calls": [{"fn": name, "args": [...]}, ...]}, one JSON
// reply on stdout, {"results": [...]} (or {"error": message}). Tensors travel as
// {"__tensor__": base64 of the little-endian data, "dtype": "uint8" | "int32" | "float32" | "float64", "shape": [...]}.
// Every function the library exports (src/index.ts) can be called, async ones too.

import * as lib from "./index.js";
import { Tensor, TypedArray } from "./tensor.js";

const DTYPES: Record<string, { new (buffer: ArrayBuffer): TypedArray }> = {
  uint8: Uint8Array, int32: Int32Array, float32: Float32Array, float64: Float64Array,
};

function decode(value: unknown): unknown {
  if (Array.isArray(value)) return value.map(decode);
  if (value !== null && typeof value === "object") {
    const object = value as Record<string, unknown>;
    if (typeof object.__tensor__ === "string") {
      const bytes = Buffer.from(object.__tensor__, "base64");
      const buffer = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength) as ArrayBuffer;
      return { data: new DTYPES[object.dtype as string](buffer), shape: object.shape as number[] } as Tensor;
    }
    return Object.fromEntries(Object.entries(object).map(([key, item]) => [key, decode(item)]));
  }
  return value;
}

function dtypeOf(data: TypedArray): string {
  if (data instanceof Uint8Array || data instanceof Uint8ClampedArray) return "uint8";
  if (data instanceof Int32Array) return "int32";
  if (data instanceof Float32Array) return "float32";
  return "float64";
}

function encode(value: unknown): unknown {
  if (ArrayBuffer.isView(value)) {
    const data = value as TypedArray;
    return encode({ data, shape: [data.length] });
  }
  if (Array.isArray(value)) return value.map(encode);
  if (value !== null && typeof value === "object") {
    const object = value as Record<string, unknown>;
    if (ArrayBuffer.isView(object.data) && Array.isArray(object.shape)) {
      const data = object.data as TypedArray;
      const bytes = Buffer.from(data.buffer, data.byteOffset, data.byteLength);
      return { __tensor__: bytes.toString("base64"), dtype: dtypeOf(data), shape: object.shape };
    }
    return Object.fromEntries(Object.entries(object).map(([key, item]) => [key, encode(item)]));
  }
  return value;
}

async function main(): Promise<void> {
  const chunks: Buffer[] = [];
  for await (const chunk of process.stdin) chunks.push(chunk as Buffer);
  const request = JSON.parse(Buffer.concat(chunks).toString("utf8")) as { calls: { fn: string; args: unknown[] }[] };
  const functions = lib as unknown as Record<string, (...args: unknown[]) => unknown>;
  try {
    const results = [];
    for (const call of request.calls) {
      const fn = functions[call.fn];
      if (typeof fn !== "function") throw new Error(`lsr-web exports no function ${call.fn}`);
      results.push(encode(await fn(...(decode(call.args) as unknown[]))));
    }
    process.stdout.write(JSON.stringify({ results }));
  } catch (error) {
    process.stdout.write(JSON.stringify({ error: error instanceof Error ? `${error.message}\n${error.stack}` : String(error) }));
  }
}

await main();
