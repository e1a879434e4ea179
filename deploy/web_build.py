"""Build the web runtime (``deploy/web``, TypeScript on onnxruntime-web) with npm: ``npm ci`` from the committed lock
file when its packages are missing, then ``npm run build`` (type check, then esbuild) when a source is newer than
the bundle. ``lsr export --web`` and the tests that compare each browser step with its Python reference call
``ensure_built``.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

from landmarks.exceptions import LandmarksError

WEB = Path(__file__).resolve().parent / "web"
DIST = WEB / "dist"
BUNDLES = ("app.js", "tracker.worker.js", "lsr.node.mjs")


class WebBuildError(LandmarksError):
    """npm is missing, or installing or building the web runtime failed (the message says which and why)."""


def _newest_source() -> float:
    sources = [*WEB.joinpath("src").rglob("*.ts"), WEB / "build.mjs", WEB / "package-lock.json", WEB / "tsconfig.json"]
    return max(path.stat().st_mtime for path in sources)


def _run(command: list[str], what: str) -> None:
    done = subprocess.run(command, cwd=WEB, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stdout + done.stderr).strip().splitlines()[-15:]
        raise WebBuildError(f"{what} failed in {WEB} ({' '.join(command)}):\n" + "\n".join(tail))


def ensure_built() -> Path:
    """The built ``deploy/web/dist`` folder (app.js for browsers, lsr.node.mjs for Node), building it when stale."""
    if shutil.which("npm") is None or shutil.which("node") is None:
        raise WebBuildError("the web runtime needs Node.js 20+ and npm (e.g. apt-get install nodejs npm)")
    if not (WEB / "node_modules" / "onnxruntime-web").is_dir():
        _run(["npm", "ci", "--no-audit", "--no-fund"], "installing the web runtime's packages (npm ci)")
    bundles = [DIST / name for name in BUNDLES]
    if not all(path.is_file() for path in bundles) or min(path.stat().st_mtime for path in bundles) < _newest_source():
        _run(["npm", "run", "build"], "building the web runtime (npm run build)")
    return DIST


def onnxruntime_files() -> list[Path]:
    """The onnxruntime-web files a page needs beside app.js: its WASM-only ES module and the WASM (SIMD, threads)
    build (14 MB), and the build of the GPU backends (deploy/web/src/backend.ts GPU_RUNTIME: WebGPU and WebNN through
    JSEP, 28 MB more), which a browser fetches only where it runs the frame generator on one of them."""
    dist = WEB / "node_modules" / "onnxruntime-web" / "dist"
    return [dist / "ort.wasm.min.mjs", dist / "ort-wasm-simd-threaded.mjs", dist / "ort-wasm-simd-threaded.wasm",
            dist / "ort.min.mjs", dist / "ort-wasm-simd-threaded.jsep.mjs", dist / "ort-wasm-simd-threaded.jsep.wasm"]
