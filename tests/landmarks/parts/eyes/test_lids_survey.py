"""lsr face-models lids: the survey's summary on gaps made here, and its one-line error without clips."""

from __future__ import annotations

import numpy as np

from landmarks.parts.eyes.lids_survey import summary


def test_summary_finds_the_people_who_blink_and_their_closed_share():
    rng = np.random.default_rng(0)
    gaps = {}
    for person in range(6):
        open_gap = 0.10 + 0.01 * person
        frames = list(open_gap + 0.002 * rng.standard_normal(40))
        if person % 2 == 0:  # three of them blink: one frame at 0.35 of their open gap
            frames[7] = 0.35 * open_gap
        gaps[f"real{person:03d}"] = {"mesh": frames, "refined": frames}
    line = summary(gaps, "refined")
    assert "6 people" in line and "3 blink" in line and "closed / open median 0.35" in line


def test_the_command_refuses_a_folder_without_clips_in_one_line(tmp_path, capsys):
    from lsr.cli import main

    code = main(["face-models", "lids", str(tmp_path)])
    message = capsys.readouterr().err.strip()
    assert code != 0 and message.startswith("lsr: error:") and "real_talking_heads" in message and "\n" not in message
