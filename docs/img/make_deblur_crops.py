"""Render the deblurring figures of docs/deblurring.md: a moving person with and without the structure guard.

Usage: .venv/bin/python docs/img/make_deblur_crops.py [--vplab PATH]
Writes docs/img/person-deblur.png (the synthetic person clip: generated, committed) and, with --vplab (default
../shared/videos/vplab_C.avi when present), docs/img/vplab_C-229-deblur.png (crops of a shared clip whose licence
is unknown: made locally, kept out of git). Columns: deblurring with the colour test alone (before the guard),
with the structure guard (the default), and no deblurring; the synthetic figure adds the truth.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pipeline.stages import deblur  # noqa: E402
from pipeline.runtime.observer import NullObserver  # noqa: E402
from pipeline.runtime.source import ArraySource  # noqa: E402
from pipeline.stabilize import StabilizeConfig, stabilize, stabilize_source  # noqa: E402
from pipeline.evaluation.synthetic import SyntheticConfig, generate  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
GUARDED = StabilizeConfig()
COLOUR_ONLY = StabilizeConfig(deblur=deblur.DeblurConfig(structure_min=None))


class _Keep(NullObserver):
    """Keeps frame ``index``'s deblurring result (output and the frame it was handed) and its output transform."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.result = None
        self.orig_from_out = None

    def on_frame(self, result) -> None:
        if result.stamp.index == self.index:
            self.result = result.deblur
            self.orig_from_out = result.warp.orig_from_out


def _panel(rows, titles, path: Path, box) -> None:
    (y0, y1), (x0, x1) = box
    fig, axes = plt.subplots(1, len(rows), figsize=(3.2 * len(rows), 3.2 * (y1 - y0) / (x1 - x0) + 0.5), dpi=110)
    for ax, image, title in zip(axes, rows, titles):
        ax.imshow(image[y0:y1, x0:x1], interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    print(f"wrote {path}")


def synthetic_figure() -> None:
    video = generate(SyntheticConfig(n_frames=30, object_kind="person", image="chelsea", seed=3))
    t = 5
    kept = {}
    for name, config in (("colour", COLOUR_ONLY), ("guarded", GUARDED)):
        keep = _Keep(t)
        stabilize_source(ArraySource(video.frames, fps=30, name="person"), None, config, observer=keep)
        kept[name] = keep
    truth = video.render_view(t, np.linalg.inv(kept["guarded"].orig_from_out))
    ys, xs = np.nonzero(video.object_view_mask(t, np.linalg.inv(kept["guarded"].orig_from_out)))
    box = ((max(ys.min() - 20, 0), min(ys.max() + 20, truth.shape[0])),
           (max(xs.min() - 40, 0), min(xs.max() + 40, truth.shape[1])))
    _panel([kept["colour"].result.frame, kept["guarded"].result.frame, kept["guarded"].result.before, truth],
           ["colour test only (before)", "structure guard (default)", "no deblurring", "truth (sharp)"],
           HERE / "person-deblur.png", box)


def vplab_figure(path: Path) -> None:
    t = 229
    kept = {}
    for name, config in (("colour", COLOUR_ONLY), ("guarded", GUARDED)):
        keep = _Keep(t)
        stabilize(path, None, config, observer=keep)
        kept[name] = keep
    _panel([kept["colour"].result.frame, kept["guarded"].result.frame, kept["guarded"].result.before],
           ["colour test only (before)", "structure guard (default)", "--no-deblur"],
           HERE / "vplab_C-229-deblur.png", ((40, 240), (200, 400)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vplab", type=Path, default=ROOT.parent / "shared" / "videos" / "vplab_C.avi",
                        help="the shared clip vplab_C.avi (skipped when absent)")
    args = parser.parse_args()
    synthetic_figure()
    if args.vplab.exists():
        vplab_figure(args.vplab)


if __name__ == "__main__":
    main()
