"""``lsr demo``: the README's main job on a fresh machine, with nothing to download.

Until a trained model exists the demo runs the landmarks toolkit on a bundled
photo (scikit-image's astronaut, public domain) and says where the results are.
"""

from __future__ import annotations

from pathlib import Path


def run_demo(out: Path) -> Path:
    """Write out/astronaut.png, annotate it into out/landmarks/; returns that folder."""
    import skimage.data

    from landmarks.annotate import annotate_path
    from landmarks.imageio import write_image

    out = Path(out)
    image_path = out / "astronaut.png"
    write_image(image_path, skimage.data.astronaut())
    result_dir = out / "landmarks"
    summary = annotate_path(image_path, result_dir)
    yaw, pitch, roll = summary["pose_yaw_pitch_roll_deg"][0]
    print(f"demo: input {image_path}")
    print(f"demo: 68 landmarks -> {result_dir / 'landmarks.npy'}; overlay -> {result_dir / 'overlay.png'}")
    print(f"demo: head pose yaw {yaw:+.1f}, pitch {pitch:+.1f}, roll {roll:+.1f} degrees")
    print(f"demo: details in {result_dir / 'summary.json'}")
    return result_dir
