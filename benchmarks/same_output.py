"""Check that a change kept behaviour: stabilize the same inputs with the working tree and with another revision,
and compare the decoded output frames.

    .venv/bin/python benchmarks/same_output.py --base REV [--clip PATH ...] [--mode full] [--out DIR]

REV is checked out into a temporary worktree and run with this environment's Python (PYTHONPATH pointing at
it), so both sides use the same libraries. Inputs: a synthetic clip (the demo's generator at its defaults)
and the given clips (default: vplab_C and zhangyilang_03 from ../shared/videos, when present). Prints, per
input, the frame counts, how many frames differ and the largest difference; exits 1 if any output differs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
VIDEOS = REPO.parent / "shared" / "videos"
DEFAULT_CLIPS = ("vplab_C.avi", "zhangyilang_03_input.avi")


def _stabilize(tree: Path, clip: Path, out: Path, mode: str) -> None:
    env = dict(os.environ, PYTHONPATH=str(tree))
    subprocess.run([sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(out), "--mode", mode,
                    "--overwrite"], cwd=tree, env=env, check=True, stdout=subprocess.DEVNULL)


def _frames(path: Path) -> list[np.ndarray]:
    from pipeline.runtime.video_reader import VideoReader

    with VideoReader(path) as reader:
        return [frame.rgb for frame in reader]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the revision to compare the working tree with")
    parser.add_argument("--clip", type=Path, action="append", default=None)
    parser.add_argument("--mode", default="full", choices=("full", "none", "crop"))
    parser.add_argument("--out", type=Path, default=None, help="keep the outputs here (default: a temporary folder)")
    args = parser.parse_args(argv)
    from pipeline.evaluation import synthetic

    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        out = args.out or scratch / "out"
        out.mkdir(parents=True, exist_ok=True)
        base = scratch / "base"
        subprocess.run(["git", "worktree", "add", "--detach", str(base), args.base], cwd=REPO, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            demo = out / "demo_input.mp4"
            synthetic.write_video(synthetic.generate(synthetic.SyntheticConfig()), demo)
            clips = [demo] + (args.clip if args.clip is not None
                              else [VIDEOS / name for name in DEFAULT_CLIPS if (VIDEOS / name).exists()])
            differ = False
            for clip in clips:
                outputs = []
                for side, tree in (("base", base), ("tree", REPO)):
                    path = out / f"{clip.stem}.{side}.mp4"
                    _stabilize(tree, clip, path, args.mode)
                    outputs.append(_frames(path))
                a, b = outputs
                diffs = [int(np.abs(x.astype(np.int16) - y).max()) for x, y in zip(a, b)]
                changed = sum(d > 0 for d in diffs) + abs(len(a) - len(b))
                differ |= changed > 0
                print(f"{clip.name:32} frames {len(a)} / {len(b)}  differing {changed}  max diff {max(diffs, default=0)}")
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=REPO, check=False,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
