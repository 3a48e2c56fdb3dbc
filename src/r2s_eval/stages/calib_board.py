"""Stage: every recorded camera's pose from a ChArUco board take (``r2s_eval.calib.cameras``).

Writes ``{"method": "board", "cameras": {camera: {pos_offset_m, rot_offset_rad, frames_used,
frames_left_out, reprojection_px, std_position_mm, std_rotation_deg[, board_from_stated][,
intrinsics]}}}``: each camera's mount error against the model's pose, in its own frame (what the
calibrated sim is built with when ``calib.cameras.use`` is board). With
``calib.cameras.board.intrinsics``, each camera's lens as ``intrinsics``: ``{image_size [H, W],
fitted {fx, fy, cx, cy}, model {...}, focal_from_model_pct {fx, fy},
principal_point_from_model_px [dcx, dcy], distortion [k1, k2, p1, p2, k3], reprojection_px
{with_distortion, without_distortion}, views, corners, cells_covered, tilts}`` (pixels at the
take's image size; the calibrated sim takes the distortion, ``WorldParams.lens_distortion``).
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
