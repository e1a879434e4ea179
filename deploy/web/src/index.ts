// The library: every step of the per-frame path that runs outside the ONNX graphs, each the port of a named Python
// reference (deploy/README.md lists them in order).
export * from "./tensor.js";
export * from "./geometry.js";
