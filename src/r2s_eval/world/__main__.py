"""Check a world and look at it before a run.

    python -m r2s_eval.world [NAME] [--experiment EXPERIMENT] [--dataset DIR [--world-params FILE]] [--out DIR]

NAME is a world of the ``world`` config group (``conf/world/<NAME>.yaml``; default: the
experiment's, ``tabletop``), shown with all its tasks from their own start regions.
``--experiment`` (default ``demo``) is the experiment composed with it; a world it does not
name takes the settings that follow the world from it: the calibration camera, the judges'
video camera and the policies' cameras default to its first recorded fixed camera
(``r2s_eval.config``). The composition is checked like any run: a wrong entry stops with one
line naming the key and the file that set it. Then the world's physics is checked
(``r2s_eval.sim.world_check``: the robot held at home stays within its joint limits, each
gripper holds each object a task picks when it lifts it); each problem is one line. Writes
``starts.png`` (every camera at a sampled start of each task, the start poses drawn in, each
panel 320 px high unless ``--size`` says otherwise) and, with ``--dataset`` (a LeRobotDataset v3),
``dataset.png``: per task, its first episode's first frame of each camera beside the simulation
rendered at the poses the calibration estimates from it, with the simulation's robot and
objects outlined on the recorded frame; ``--world-params FILE`` (a calibrated sim's) renders
through its cameras, light and colours. It names the files this call wrote, nothing else;
without ``--dataset``, a ``dataset.png`` an earlier call left in the folder (perhaps of another
world) is removed, and said so.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from r2s_eval.config import compose_config, stop_before_running
from r2s_eval.errors import R2SError
from r2s_eval.paths import CONF_DIR
from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.sim.grasping import grasp_settings
from r2s_eval.sim.world_check import check_world
from r2s_eval.world.preview import DATASET_PNG, PANEL_PX, STARTS_PNG, preview


def main(args: argparse.Namespace) -> None:
    overrides = []
    if args.world:  # the named world's own tasks and start regions (the experiment's are for its own world)
        world_file = CONF_DIR / "world" / f"{args.world}.yaml"
        tasks = list((yaml.safe_load(world_file.read_text()) or {}).get("tasks") or {}) if world_file.is_file() else []
        overrides = [f"world={args.world}"] + (["suite=world", f"tasks=[{','.join(tasks)}]"] if tasks else [])
    try:  # checked as a run checks it, and a wrong entry printed as a run prints it
        cfg = compose_config(CONF_DIR, args.experiment, overrides)
    except R2SError as err:
        stop_before_running(err)
    world = cfg["world"]
    try:
        check_world(world, cfg["tasks"], grasp_settings(cfg["teleop"]["operator"]))  # the operator's grasp
    except R2SError as err:
        stop_before_running(err)
    # Panels large enough to judge a camera's pose by, in the world's aspect.
    size = args.size or (PANEL_PX, round(PANEL_PX * world["image_width"] / world["image_height"]))
    stale = Path(args.out) / DATASET_PNG
    stale = stale if args.dataset is None and stale.is_file() else None
    params = load_world_params(args.world_params) if args.world_params else None
    out = preview(world, args.out, args.cameras or world["cameras"], tuple(size), args.seed, args.dataset, cfg["calib"],
                  params)
    print(f"wrote {out / STARTS_PNG}")
    if args.dataset is not None:
        print(f"wrote {out / DATASET_PNG}")
    elif stale is not None:
        print(f"removed {stale} (an earlier call's, with --dataset)")


def parser() -> argparse.ArgumentParser:
    p = _cli.parser(__doc__.split("\n")[0], cfg=False)
    p.add_argument("world", nargs="?", help="a world of conf/world (default: the experiment's)")
    p.add_argument("--dataset", help="a LeRobotDataset v3 recorded in this world: its first frames beside the sim")
    p.add_argument("--world-params", help="a calibrated sim's world parameters (results/calib/world_params.json): "
                                          "its cameras, light and colours; default: the model's")
    p.add_argument("--experiment", default="demo", help="the experiment composed with the world (default: demo): "
                                                        "its cameras and calibration settings")
    p.add_argument("--out", default="reports/world_preview", help="folder for starts.png (and dataset.png)")
    p.add_argument("--cameras", nargs="+", help="default: the experiment's world.cameras")
    p.add_argument("--size", nargs=2, type=int, metavar=("H", "W"), help=f"each panel's size in starts.png (default: {PANEL_PX} px high, the world's aspect)")
    p.add_argument("--seed", type=int, default=0, help="seeds the sampled starts")
    return p


if __name__ == "__main__":
    _cli.run(main, parser())
