"""Stage: every recorded camera's pose from a ChArUco board take (``r2s_eval.calib.cameras``).

Writes ``{"method": "board", "cameras": {camera: {pos_offset_m, rot_offset_rad, frames_used,
frames_left_out, reprojection_px, std_position_mm, std_rotation_deg[, board_from_stated]}}}``:
each camera's mount error against the model's pose, in its own frame (what the calibrated sim
is built with when ``calib.cameras.use`` is board).
"""

from __future__ import annotations

from r2s_eval.calib.cameras import calibrate_from_board
from r2s_eval.stages import _cli
from r2s_eval.utils.io import write_json

READS = ("calib.cameras.board", "world", "tasks")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    write_json(args.out, calibrate_from_board(args.take, cfg["world"], cfg["calib.cameras.board"], cfg["tasks"]),
               provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--take", required=True, help="the board take (a LeRobotDataset v3, or images + states.csv)")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
