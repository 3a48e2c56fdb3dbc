"""Stage: validate the teleop dataset and write the episode index and first frames."""

from __future__ import annotations

from r2s_eval.data import IngestSpec, ingest_dataset
from r2s_eval.sim.build import feature_ranges
from r2s_eval.sim.robot import world_robot
from r2s_eval.stages import _cli
from r2s_eval.utils.io import atomic_dir, write_json, write_parquet

# config paths the --cfg slice holds (see _reads.py)
READS = ("world.cameras", "world.robot", "world.rig", "calib.camera", "ingest.repo_id", "ingest.min_length",
         "ingest.max_length", "ingest.drop_bad_episodes", "ingest.check_videos")
PROVIDED = ("instructions",)  # the rule adds {task: instruction} of the tasks evaluated


def main(args) -> None:
    cfg = args.cfg
    robot = world_robot({"robot": cfg["world.robot"], "rig": cfg["world.rig"], "cameras": cfg["world.cameras"]})
    spec = IngestSpec(
        cameras=list(cfg["world.cameras"]),
        feature_names=robot.feature_names,
        fps=round(robot.control_hz),
        tasks={instruction: key for key, instruction in cfg["instructions"].items()},
        first_frame_camera=cfg["calib.camera"],
        min_length=cfg["ingest.min_length"],
        max_length=cfg["ingest.max_length"],
        drop_bad_episodes=cfg["ingest.drop_bad_episodes"],
        check_videos=cfg["ingest.check_videos"],
        feature_ranges=feature_ranges(robot),
    )
    with atomic_dir(args.frames) as frames_dir:
        index, report = ingest_dataset(args.dataset, cfg["ingest.repo_id"], spec, frames_dir)
    write_parquet(args.index, index, metadata={"stage": "ingest", "dataset": str(args.dataset)})
    write_json(args.report, report, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--dataset", required=True)
    p.add_argument("--index", required=True)
    p.add_argument("--report", required=True)
    p.add_argument("--frames", required=True)
    _cli.run(main, p)
