"""End to end over HTTP with gradio_client: synthetic source + driver in, a playable H.264 video out."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow


def call_reenact(url, source, driver, **options):
    from gradio_client import Client, handle_file

    client = Client(url, verbose=False)
    settings = {"k": 1, "motion": "relative", "smooth": True, "paste_back": False, "finetune_steps": 0,
                "runtime": "torch", "watermark": True, **options}
    return client.predict(
        [handle_file(str(source))], settings["k"], handle_file(str(driver)), settings["motion"], settings["smooth"],
        settings["paste_back"], settings["finetune_steps"], settings["runtime"], settings["watermark"],
        api_name="/reenact",
    )


def decode(path):
    import av

    with av.open(str(path)) as container:
        streams = {stream.type: stream.codec_context.name for stream in container.streams}
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
        comment = container.metadata.get("comment", "")
    return streams, frames, comment


def test_reenact_returns_playable_video_with_every_frame(app_server, app_server_weights, app_inputs):
    import json

    from landmarks.io.video import probe_video

    driver_frames = probe_video(app_inputs["driver"]).frames
    # gr.State outputs are not part of the API: video, summary, shots, averaging, panel, scrubber, timing, coverage.
    video, summary, shots, averaging, panel, _scrubber, timing, coverage = call_reenact(
        app_server, app_inputs["source"], app_inputs["driver"]
    )
    path = video["video"] if isinstance(video, dict) else video
    streams, frames, comment = decode(path)
    assert streams["video"] == "h264" and streams.get("audio") == "aac"  # the driver's audio is kept
    assert len(frames) == driver_frames
    config = json.loads((app_server_weights / "config.json").read_text())
    crop = config["resolution"] * (config.get("crop_scale", 2) if config["variant"] == "warp_guided" else 1)  # default_crop_size
    assert frames[0].shape == (crop, crop, 3)  # the served model's crop (no paste-back)
    assert float(np.std(frames[0])) > 1.0  # a picture, not a blank frame
    assert "synthetic" in comment  # provenance metadata
    assert f"{driver_frames} frame(s)" in summary and "audio kept" in summary
    assert len(shots) == 1 and len(averaging) == 2  # one shot alone + the K-shot average
    assert panel is not None and "synthesis" in timing
    assert coverage is not None  # the picture of what the shots cover (landmarks.parts.coverage.coverage_picture)


def test_paste_back_puts_the_result_into_the_source_scene(app_server, app_inputs, tmp_path):
    """The result has the source photo's size (wider than the 128^2 driver) and, far from the head, its pixels."""
    import numpy as np

    from landmarks.io.image_files import read_image, write_image

    source = read_image(app_inputs["source"])
    wide = np.pad(source, ((0, 0), (32, 32), (0, 0)), mode="edge")
    write_image(tmp_path / "wide.png", wide)
    video, *_ = call_reenact(app_server, tmp_path / "wide.png", app_inputs["driver"], paste_back=True, watermark=False)
    _, frames, _ = decode(video["video"] if isinstance(video, dict) else video)
    assert len(frames) == 5 and frames[0].shape == (128, 192, 3)  # conftest: 5 driver frames of 128^2
    border = np.abs(frames[0][:, :16].astype(int) - wide[:, :16]).mean()  # the padded strip, far from the head
    assert border < 8


def test_source_without_face_is_a_readable_error(app_server, app_inputs):
    from gradio_client.exceptions import AppError

    with pytest.raises(AppError, match="no face found"):
        call_reenact(app_server, app_inputs["no_face"], app_inputs["driver"])


def test_unsupported_driver_is_a_readable_error(app_server, app_inputs, tmp_path):
    from gradio_client.exceptions import AppError

    corrupt = tmp_path / "broken.mp4"
    corrupt.write_bytes(b"not a video" * 100)
    with pytest.raises(AppError, match="corrupt"):
        call_reenact(app_server, app_inputs["source"], corrupt)
