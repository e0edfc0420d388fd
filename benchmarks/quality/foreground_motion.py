"""The camera's motion with large figures in front of it: residual shake against ground truth per case and seed,
each case beside the same scene with a small figure, in full and crop mode; and the shared clips' jitter, this tree
against a base revision.

Ground truth: pipeline/evaluation/foreground.py (a shaken, panned camera over a photograph; figures dressed in cuts of
the photograph walking across the view: large, fast, entering and leaving, three at once, with blurred frames).
Residual shake: RMS of the high-pass of where the output's centre looks in the world (px). The bound (issue 41):
each seed's shake at most 1.5x that of the same seed's small-figure scene. Wrong pairs: pairs whose motion is more
than 2 px (frame corners) off the true camera's.

Shared clips: `ffviz stabilize --mode none --no-deblur` (its path is full and crop mode's; its jitter is theirs) by
this tree and by --base in a worktree, `ffviz metrics`' residual jitter of each; noise: how much the same tree's
jitter moves when only the encoding changes (--crf 18 against 28), the measure's own spread.

Usage: python -m benchmarks.quality.foreground_motion [--seeds 5] [--images coffee,astronaut,chelsea,rocket]
       [--base REV] [--no-clips] [--no-truth] [--report docs/benchmarks-robust-motion.md | --no-report]
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks import common
from pipeline.evaluation import foreground

REPORT = common.DOCS / "benchmarks-robust-motion.md"
BOUND = 1.5
MODES = ("full", "crop")


def truth_rows(images: list[str], seeds: int) -> list[str]:
    """The ground-truth table, one row per image, case and mode; printed as it is measured."""
    lines = ["| image | case | figures' share | mode | shake px by seed (wrong pairs) | x the small scene's, "
             "by seed | worst | bound 1.5x |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for image in images:
        measured: dict[tuple[str, str], list[float]] = {}
        for case in foreground.CASES.values():
            shakes = {mode: [] for mode in MODES}
            share = 0.0
            for seed in range(seeds):
                video = foreground.clip(case.name, image, seed)
                for mode, shake in foreground.residual_shakes(video, MODES).items():
                    shakes[mode].append(shake)
                    share = max(share, shake.figure_share)
            for mode in MODES:
                px = [s.px for s in shakes[mode]]
                measured[case.name, mode] = px
                base = measured[case.reference, mode]
                ratios = [a / b for a, b in zip(px, base)]
                met = "-" if case.reference == case.name else ("met" if max(ratios) <= BOUND else "NOT MET")
                line = (f"| {image} | {case.name} | {share:.2f} | {mode} | "
                        + " ".join(f"{s.px:.2f} ({s.wrong_pairs})" for s in shakes[mode])
                        + " | " + " ".join(f"{r:.2f}" for r in ratios) + f" | {max(ratios):.2f} | {met} |")
                lines.append(line)
                print(line, flush=True)
    return lines


def _jitter(tree: Path, clip: Path, out: Path, crf: int) -> tuple[float, float]:
    """(px, deg) residual jitter of ``tree``'s --mode none output of ``clip``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    subprocess.run([sys.executable, "-m", "ffviz.cli", "stabilize", str(clip), "-o", str(out), "--mode", "none",
                    "--no-deblur", "--crf", str(crf), "--overwrite"], cwd=tree, env=env, check=True,
                   stdout=subprocess.DEVNULL)
    measured = subprocess.run([sys.executable, "-m", "ffviz.cli", "metrics", str(clip), str(out), "--json"],
                              cwd=common.ROOT, check=True, capture_output=True, text=True)
    result = json.loads(measured.stdout)
    return result["residual_jitter_px"], result["residual_jitter_deg"]


def clip_rows(base: str) -> list[str]:
    """The shared clips' jitter, --base against this tree, with the measure's noise."""
    lines = [f"| clip | jitter px: {base} | this tree | change | noise (crf 18 vs 28) | jitter deg: {base} | "
             "this tree |", "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    clips = sorted(p for p in common.VIDEOS.glob("*") if p.suffix in (".mp4", ".avi"))
    with tempfile.TemporaryDirectory() as scratch:
        scratch = Path(scratch)
        worktree = scratch / "base"
        subprocess.run(["git", "worktree", "add", "--detach", str(worktree), base], cwd=common.ROOT, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for clip in clips:
                before = _jitter(worktree, clip, scratch / "before.mp4", 18)
                after = _jitter(common.ROOT, clip, scratch / "after.mp4", 18)
                coarse = _jitter(common.ROOT, clip, scratch / "coarse.mp4", 28)
                line = (f"| {clip.name} | {before[0]:.2f} | {after[0]:.2f} | {after[0] / before[0] - 1:+.1%} | "
                        f"{abs(coarse[0] / after[0] - 1):.1%} | {before[1]:.3f} | {after[1]:.3f} |")
                lines.append(line)
                print(line, flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(worktree)], cwd=common.ROOT,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return lines


def main() -> None:
    parser = common.parser(__doc__)
    parser.add_argument("--seeds", type=int, default=5, help="seeds per case (default: %(default)s)")
    parser.add_argument("--images", default="coffee,astronaut,chelsea,rocket",
                        help="the photographs the scenes are made of (default: %(default)s)")
    parser.add_argument("--base", default="HEAD", help="the revision the shared clips are compared with "
                                                       "(default: %(default)s)")
    parser.add_argument("--no-clips", action="store_true", help="ground truth only")
    parser.add_argument("--no-truth", action="store_true", help="the shared clips only")
    common.add_report(parser, REPORT)
    args = parser.parse_args()
    report = common.report_path(args)
    if not args.no_truth:
        lines = truth_rows(args.images.split(","), args.seeds)
        common.save("foreground_truth", [
            "## foreground_motion.py: large figures against a small one, on ground truth", "",
            f"{common.machine_line()}. Each scene {args.seeds} seeds, 120 frames of 640x360 "
            "(pipeline/evaluation/foreground.py); shake: the output view's residual shake in the world, px "
            "(wrong pairs: motion off the truth by > 2 px); the bound: every seed at most 1.5x its small-figure "
            "scene.", "", *lines], report)
    if not args.no_clips:
        lines = clip_rows(args.base)
        common.save("foreground_clips", [
            "## foreground_motion.py: the shared clips' jitter before and after", "",
            f"{common.machine_line()}. `--mode none --no-deblur` (the path of every mode), `ffviz metrics`' residual "
            f"jitter; before: {args.base}.", "", *lines], report)


if __name__ == "__main__":
    main()
