"""The app served in-process on 127.0.0.1 (a free port) with a tiny random model, plus small synthetic inputs."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import numpy as np
import pytest

SIZE = 128  # input pictures; the tiny model works on 64^2 crops
DRIVER_FRAMES = 5


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="session")
def app_inputs(tmp_path_factory) -> dict[str, Path]:
    """source.png (synthetic person A), driver.mp4 (person B, 5 frames, with audio), no_face.png (a gradient)."""
    from app.examples import write_clip_with_tone
    from landmarks.io.image_files import write_image
    from lsr.data.synth import render_video

    folder = tmp_path_factory.mktemp("app_inputs")
    write_image(folder / "source.png", render_video(11, 1, SIZE).frames[0])
    write_clip_with_tone(folder / "driver.mp4", render_video(12, DRIVER_FRAMES, SIZE).frames)
    ramp = np.linspace(0, 255, SIZE, dtype=np.float32)
    gradient = np.stack([np.add.outer(ramp, ramp) / 2, np.tile(ramp, (SIZE, 1)), np.full((SIZE, SIZE), 90.0)], axis=-1)
    write_image(folder / "no_face.png", gradient.astype(np.uint8))
    return {"source": folder / "source.png", "driver": folder / "driver.mp4", "no_face": folder / "no_face.png"}


@pytest.fixture(scope="session")
def tiny_app_weights(tmp_path_factory) -> Path:
    from app.handlers import random_init_weights

    return random_init_weights(tmp_path_factory.mktemp("app_weights") / "tiny")


@pytest.fixture(scope="session")
def app_server_weights(tiny_app_weights) -> Path:
    """The served model: the shipped default (what `lsr app` serves), unless LSR_APP_TEST_TINY=1 asks for speed."""
    from lsr.weights import DEFAULT_WEIGHTS, is_model_folder

    if os.environ.get("LSR_APP_TEST_TINY") == "1" or not is_model_folder(DEFAULT_WEIGHTS):
        return tiny_app_weights
    return DEFAULT_WEIGHTS


@pytest.fixture(scope="session")
def app_server(app_server_weights, tmp_path_factory):
    """URL of a running app (build_app + launch without blocking); closed and cleaned after the session."""
    pytest.importorskip("gradio")
    from app.ui import build_app, launch
    from lsr.config import AppConfig

    cfg = AppConfig(weights=app_server_weights, port=free_port(), device="cpu", max_upload_mb=5,
                    examples_dir=tmp_path_factory.mktemp("app_examples"))
    cfg.validate()
    demo, _, files = build_app(cfg)
    url = launch(demo, cfg, files, block=False)
    yield url
    demo.close()
    files.drop_all()
