"""``lsr demo`` (the README's main command): synthetic source + driver -> lsr reenact -> video + side-by-side."""

from __future__ import annotations

import pytest

from lsr.cli import main


@pytest.mark.slow
def test_demo_writes_video_side_by_side_and_still(tmp_path, capsys):
    import av

    from landmarks.io.image_files import read_image
    from models_def import LSRModel, preset_config

    weights = LSRModel(preset_config("tiny")).save_pretrained(tmp_path / "tiny")  # fast stand-in for the default
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--weights", str(weights), "--frames", "6", "--k", "2", "--finetune-steps", "2",
                 "--synthetic", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "fine-tuned on 2 shots" in printed
    for name in ("demo.mp4", "demo_side_by_side.mp4", "demo_side_by_side.png"):
        assert str(out / name) in printed  # the demo says where its outputs are
    with av.open(str(out / "demo.mp4")) as container:
        assert sum(1 for _ in container.decode(video=0)) == 6
        assert "synthetic" in container.metadata.get("comment", "").lower()
    still = read_image(out / "demo_side_by_side.png")
    assert still.shape[1] == 4 * 256  # driver | landmarks | latent layout | output, each enlarged to 256
    assert {p.name for p in (out / "inputs").iterdir()} == {"source.mp4", "driver.mp4"}
    assert not [p for p in out.rglob(".*")]  # no temp files left behind


def test_demo_without_a_model_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LSR_WEIGHTS", str(tmp_path / "missing"))
    assert main(["demo", "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert "LSR_WEIGHTS" in capsys.readouterr().err
    assert not (tmp_path / "out" / "demo.mp4").exists()


@pytest.mark.slow
def test_demo_reenacts_the_bundled_real_example_by_default(tmp_path, capsys):
    import av

    from landmarks.io.video import probe_video
    from models_def import LSRModel, preset_config

    weights = LSRModel(preset_config("tiny", variant="warp_guided")).save_pretrained(tmp_path / "tiny")
    out = tmp_path / "out"
    assert main(["demo", "--out", str(out), "--weights", str(weights), "--frames", "5", "--k", "3", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "GRID corpus" in printed and "CC BY 4.0" in printed  # says which example it is and under which licence
    assert probe_video(out / "inputs" / "source.mp4").frames == 75  # the bundled source, whole
    assert probe_video(out / "inputs" / "driver.mp4").frames == 5  # the bundled driver, cut to --frames
    with av.open(str(out / "demo.mp4")) as container:
        assert sum(1 for _ in container.decode(video=0)) == 5


def test_every_bundled_example_file_has_its_provenance_in_the_notice():
    from lsr.examples import EXAMPLES, REAL_DRIVER, REAL_SOURCE

    notice = (EXAMPLES / "NOTICE.md").read_text()
    assert "CC BY 4.0" in notice and "Cooke" in notice
    files = {path.name for path in EXAMPLES.iterdir() if path.suffix not in (".md", ".py") and path.is_file()}
    assert {REAL_SOURCE.name, REAL_DRIVER.name} <= files
    for name in files:
        assert f"`{name}`" in notice, f"{name} is bundled without its provenance in lsr/examples/NOTICE.md"
    assert sum((EXAMPLES / name).stat().st_size for name in files) < 2 * 2**20  # at most 2 MB of footage
