"""The fixed inputs of the page's per-frame benchmark (bench/stages.ts): the site of the shipped default
(``lsr export --web``'s, as tests/deploy/conftest.py's ``site`` fixture writes it) and the first frames of the bundled
driver (lsr.examples.REAL_DRIVER, as its ``driver_frames`` fixture reads them), raw.

    .venv/bin/python deploy/web/bench/prepare.py OUT [--frames 60]

writes OUT/site/ and OUT/frames.u8 with OUT/frames.json ({"shape": [T, H, W, 3]}). Run once; the benchmark reads them.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()

    from landmarks.io.video import iter_frames
    from lsr.examples import REAL_DRIVER
    from lsr.export.web_site import write_site
    from lsr.weights import resolve_weights

    args.out.mkdir(parents=True, exist_ok=True)
    if not (args.out / "site" / "site.json").is_file():
        write_site(resolve_weights(None), args.out / "site")
    frames = np.stack([frame for _, frame in zip(range(args.frames), iter_frames(REAL_DRIVER))])
    (args.out / "frames.u8").write_bytes(np.ascontiguousarray(frames, np.uint8).tobytes())
    (args.out / "frames.json").write_text(json.dumps({"shape": list(frames.shape)}))
    print(f"{args.out}: site/ and {frames.shape[0]} frames {frames.shape[1:]}")


if __name__ == "__main__":
    main()
