// The library: every step of the per-frame path that runs outside the ONNX graphs, each the port of a named Python
// reference (deploy/README.md lists them in order).
export * from "./tensor.js";
export * from "./geometry.js";
export * from "./raster.js";
export * from "./smooth.js";
export * from "./retarget.js";
export * from "./mouth.js";
export * from "./interior.js";
export * from "./eyes.js";
export * from "./lids.js";
export * from "./facedetect.js";
export * from "./facemesh.js";
export * from "./tracker.js";
export * from "./remap.js";
export * from "./tps.js";
export * from "./composite.js";
export * from "./network.js";
export * from "./session.js";
export * from "./pose.js";
export * from "./segment.js";
export * from "./encode.js";
export * from "./references.js";
export * from "./gaze.js";
export * from "./iris_warp.js";
export * from "./hysteresis.js";
export * from "./bank_rows.js";
export * from "./eye_bank.js";
