"""Check a world file and look at it before a run.

    python -m r2s_eval.world [WORLD] [--dataset DIR] [--experiment demo] [--out reports/world_preview]

WORLD is a bundled world's name (default ``tabletop``), a world folder or its ``world.yaml``. A
wrong entry stops with one line naming the file and the key. Writes ``starts.png`` (every camera
at a sampled start of each task, the start poses drawn in) and, with ``--dataset`` (a
LeRobotDataset v3), ``dataset.png``: per task, its first episode's first frame of each camera
beside the simulation rendered at the poses the calibration estimates from it. The cameras,
image size and calibration settings are the experiment's (``world``, ``calib``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from r2s_eval.config import compose_config
from r2s_eval.stages import _cli
from r2s_eval.world.preview import preview

CONF_DIR = Path(__file__).resolve().parents[3] / "conf"


def main(args: argparse.Namespace) -> None:
    cfg = compose_config(CONF_DIR, args.experiment)
    world = cfg["world"]
    size = args.size or (int(world["image_height"]), int(world["image_width"]))
    out = preview(args.world, args.out, args.cameras or world["cameras"], tuple(size), args.seed, args.dataset,
                  cfg["calib"], world)
    for png in sorted(out.glob("*.png")):
        print(f"wrote {png}")


def parser() -> argparse.ArgumentParser:
    p = _cli.parser(__doc__.split("\n")[0], cfg=False)
    p.add_argument("world", nargs="?", default="tabletop", help="a bundled world's name, a world folder or its file")
    p.add_argument("--dataset", help="a LeRobotDataset v3 recorded in this world: its first frames beside the sim")
    p.add_argument("--experiment", default="demo", help="the experiment whose cameras and calibration to use")
    p.add_argument("--out", default="reports/world_preview", help="folder for starts.png (and dataset.png)")
    p.add_argument("--cameras", nargs="+", help="default: the experiment's world.cameras")
    p.add_argument("--size", nargs=2, type=int, metavar=("H", "W"), help="image size of starts.png (default: the world's)")
    p.add_argument("--seed", type=int, default=0, help="seeds the sampled starts")
    return p


if __name__ == "__main__":
    _cli.run(main, parser())
