"""Render docs/img/compare.jpg: a frame of `ffviz compare` on the built-in demo's clip (generated: ours to publish;
the shared real clips' licence is unknown, so no picture shows them).

Usage: .venv/bin/python docs/img/make_compare.py [WORK_DIR]   (default: a temporary folder)
Panels: the input, ffviz --mode crop, and ffmpeg's vid.stab (default options, as the benchmark's peer) when
Debian's ffmpeg with vid.stab is on PATH; the picture is the output's frame 42.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2

from ffviz import cli
from pipeline.evaluation import synthetic
from pipeline.runtime.video_reader import VideoReader

SECONDS, FRAME = 4, 42
OUT = Path(__file__).resolve().parent / "compare.jpg"


def vidstab(source: Path, target: Path, work: Path) -> bool:
    """ffmpeg vid.stab's two passes on the first SECONDS of source; False when ffmpeg or vid.stab is missing."""
    if shutil.which("ffmpeg") is None:
        return False
    trf = work / "transforms.trf"
    common = ["ffmpeg", "-v", "error", "-y", "-i", str(source), "-t", str(SECONDS)]
    try:
        subprocess.run([*common, "-vf", f"vidstabdetect=result={trf}", "-f", "null", "-"], check=True)
        subprocess.run([*common, "-vf", f"vidstabtransform=input={trf}", "-c:v", "libx264", "-crf", "18",
                        str(target)], check=True)
    except subprocess.CalledProcessError:
        return False
    return True


def main(work: Path) -> None:
    clip = work / "demo_input.mp4"  # ./run demo's input: seed 0, 120 frames
    synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig(n_frames=120, seed=0)), clip)
    ffviz_out, vidstab_out, sbs = work / "ffviz_crop.mp4", work / "vidstab.mp4", work / "sbs.mp4"
    assert cli.main(["stabilize", str(clip), "-o", str(ffviz_out), "--mode", "crop", "--preview", str(SECONDS),
                     "--overwrite"]) == 0
    panels, labels = [str(clip), str(ffviz_out)], "demo input,ffviz --mode crop"
    if vidstab(clip, vidstab_out, work):
        panels.append(str(vidstab_out))
        labels += ",ffmpeg vid.stab"
    assert cli.main(["compare", *panels, "-o", str(sbs), "--labels", labels, "--shortest", "--overwrite"]) == 0
    with VideoReader(sbs) as reader:
        for frame in reader:
            if frame.index == FRAME:
                cv2.imwrite(str(OUT), cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
                print(f"wrote {OUT}")
                return


if __name__ == "__main__":
    if len(sys.argv) > 1:
        main(Path(sys.argv[1]))
    else:
        with tempfile.TemporaryDirectory() as folder:
            main(Path(folder))
