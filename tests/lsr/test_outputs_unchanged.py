"""The house may move; what it draws may not (issue 64): frames of ``lsr demo`` and of ``lsr reenact --paste-back``
on the shared clips, hashed and compared with the digests recorded before the move (the torch runtime; the default
onnx one is held to the same frames' statistics).

``python tests/lsr/test_outputs_unchanged.py --record`` rewrites ``outputs_unchanged.json`` (only when a change of
output is meant). The digests are bit-exact on the machine kind they were recorded on (torch's CPU capability and
version are recorded with them); elsewhere floating point may differ in the last bit, and the test compares each
frame's mean and spread instead.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

RECORD = Path(__file__).with_name("outputs_unchanged.json")
FRAMES = 12  # the first frames of each driver: enough to pass every stage, the bank and the scene included
SHARED = {"shared_sun_by_tpsmm": ("clips/musetalk_sun.mp4", "clips/tpsmm_driving.mp4"),
          "shared_tpsmm_by_sun": ("clips/tpsmm_driving.mp4", "clips/musetalk_sun.mp4")}


def machine_key() -> str:
    """torch's version and CPU capability, and the CPU's family and model where Linux says them: two AMD EPYC kinds
    with AVX-512 (the same key without the model) drew the demo's frames a last bit apart."""
    import torch

    from lsr.eval.machine import cpu_fields

    cpu = cpu_fields()
    kind = (f" cpu {cpu.get('vendor_id', '?')} family {cpu.get('cpu family', '?')} model {cpu.get('model', '?')}"
            if cpu else "")
    return f"torch {torch.__version__} {torch.backends.cpu.get_cpu_capability()}{kind}"


def frame_digests(source: Path, driver: Path, *, side_by_side: bool, frames: int = FRAMES,
                  runtime: str = "torch") -> dict:
    """Re-enact ``frames`` frames as ``lsr reenact --paste-back`` (and the demo) do, one thread; each frame's
    sha256 and its (mean, std) per channel, and the side-by-side panels' when asked. numpy's BLAS on one thread, as
    the ``lsr`` command sets it (``single_blas_thread``): its rounding depends on its thread count."""
    from lsr.core.overlap import single_blas_thread

    single_blas_thread()
    from lsr.config import ReenactConfig
    from lsr.commands.reenact import make_reenactor
    from lsr.writer import side_by_side_frame
    from lsr.weights import resolve_weights

    cfg = ReenactConfig(weights=resolve_weights(None), source=source, driver=driver, out=Path("unused.mp4"),
                        k=8, paste_back=True, threads=1, progress=False, runtime=runtime)
    cfg.validate()
    reenactor = make_reenactor(cfg)
    reenactor.encode_subject(source, k=cfg.k)
    stream = reenactor.reenact(driver, paste_back=True, with_layout=side_by_side)
    out: dict[str, list] = {"sha256": [], "stats": []}
    try:
        for frame in stream:
            images = [frame.image]
            if side_by_side:
                images.append(side_by_side_frame(frame, reenactor.backend.layout_kind, reenactor.crop_size))
            digest = hashlib.sha256()
            for image in images:
                digest.update(np.ascontiguousarray(image).tobytes())
            out["sha256"].append(digest.hexdigest())
            pixels = np.concatenate([image.reshape(-1, 3) for image in images]).astype(np.float64)
            out["stats"].append([*pixels.mean(0).round(3).tolist(), *pixels.std(0).round(3).tolist()])
            if len(out["sha256"]) == frames:
                break
    finally:
        stream.close()
    return out


def cases(shared_root: Path | None) -> dict[str, tuple[Path, Path, bool]]:
    from lsr.examples import REAL_DRIVER, REAL_SOURCE

    found = {"demo": (Path(REAL_SOURCE), Path(REAL_DRIVER), True)}
    if shared_root is not None:
        for name, (source, driver) in SHARED.items():
            found[name] = (shared_root / source, shared_root / driver, False)
    return found


def _check(name: str, source: Path, driver: Path, side_by_side: bool) -> None:
    recorded = json.loads(RECORD.read_text())
    expected = recorded["cases"][name]
    got = frame_digests(source, driver, side_by_side=side_by_side)
    assert len(got["sha256"]) == len(expected["sha256"])
    if recorded["machine"] == machine_key():
        assert got["sha256"] == expected["sha256"], f"{name}: the frames changed"
    else:  # another CPU kind: the last bit may differ, the picture may not
        np.testing.assert_allclose(got["stats"], expected["stats"], atol=0.5)


@pytest.mark.slow
def test_demo_frames_unchanged():
    source, driver, side_by_side = cases(None)["demo"]
    _check("demo", source, driver, side_by_side)


@pytest.mark.slow
def test_the_default_runtime_draws_the_recorded_demo_frames():
    """The default (--runtime auto: the exported graphs on onnxruntime) draws the frames recorded with torch, to the
    rounding of the last bit (each frame's mean and spread per channel)."""
    from lsr.config import ReenactConfig

    assert ReenactConfig().resolved_runtime == "onnx"
    source, driver, side_by_side = cases(None)["demo"]
    got = frame_digests(source, driver, side_by_side=side_by_side, runtime="onnx")
    expected = json.loads(RECORD.read_text())["cases"]["demo"]
    np.testing.assert_allclose(got["stats"], expected["stats"], atol=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(SHARED))
def test_shared_clip_frames_unchanged(shared_data, name):
    source, driver, side_by_side = cases(shared_data)[name]
    _check(name, source, driver, side_by_side)


if __name__ == "__main__" and "--record" in sys.argv:
    root_dir = Path(__file__).resolve().parents[2]
    sys.path[0] = str(root_dir)  # not this test folder, whose "lsr" would shadow the package
    from tests.conftest import shared_data_dir

    root = shared_data_dir()
    record = {"machine": machine_key(), "frames": FRAMES,
              "cases": {name: frame_digests(s, d, side_by_side=sbs)
                        for name, (s, d, sbs) in cases(root if (root / "README.md").is_file() else None).items()}}
    RECORD.write_text(json.dumps(record, indent=1) + "\n")
    print(f"recorded {', '.join(record['cases'])} on {record['machine']} -> {RECORD}")
