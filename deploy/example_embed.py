"""Embedding example: LSR re-enactment inside another application, with no torch installed.

Copy this file. It needs numpy, onnxruntime and opencv (and the ``landmarks`` toolkit, whose face models run on onnxruntime) and an ONNX
bundle made once with ``lsr export --weights MODEL_DIR --out BUNDLE``.

    python deploy/example_embed.py BUNDLE source.jpg driver.mp4 out.mp4     # or out_folder/ for PNG frames
"""

from __future__ import annotations

import sys
from pathlib import Path

from lsr.core.overlap import single_blas_thread
from lsr.core.provenance import draw_watermark, provenance_metadata
from deploy.runtime import OnnxReenactor
from lsr.core.inputs import describe_driver
from landmarks.io.image_files import write_image
from landmarks.io.video import VideoWriter


def reenact_to(bundle: str, source: str, driver: str, out: str) -> int:
    """Re-enact ``source`` with ``driver`` into ``out`` (.mp4, or a folder of PNGs). Returns the frame count."""
    single_blas_thread()  # numpy's BLAS on one thread: the frame loop's stages need the cores its idle threads spin on
    reenactor = OnnxReenactor(bundle)  # loads both graphs once
    reenactor.encode_subject(source)  # K shots -> latents, cached on the reenactor
    info = describe_driver(driver)  # frame count, fps, size, audio
    frames = reenactor(driver, paste_back=info.kind != "landmarks")  # a generator: one frame at a time
    count = 0
    if out.endswith(".mp4"):
        audio = driver if info.has_audio else None
        # Mark the output as synthetic: container metadata and a visible watermark.
        with VideoWriter(out, info.fps, audio_from=audio, metadata=provenance_metadata(runtime="onnx")) as writer:
            for frame in frames:
                writer.write(draw_watermark(frame.image))
                count += 1
    else:
        Path(out).mkdir(parents=True, exist_ok=True)
        for frame in frames:
            write_image(Path(out) / f"{frame.index:06d}.png", draw_watermark(frame.image))
            count += 1
    stats = reenactor.last_stats
    print(f"{count} frames ({stats.no_face} without a face, passed through) -> {out}")
    return count


if __name__ == "__main__":
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    reenact_to(*sys.argv[1:5])
