"""Stage: the reality twin records a ChArUco board take (``r2s_eval.twin.board_take``).

A lab records its own (``calib.cameras.board_take``); the twin records one the way a lab would:
the board lying on the table where ``calib.cameras.board.pose`` says, the arms moving through
poses, every recorded camera at its native resolution, as a LeRobotDataset v3. When the
calibration fits the lenses (``calib.cameras.board.intrinsics``) the take also shows them what
they need: the arms' cameras swept over the board, then the board held up to each fixed camera
(``teleop.board_take.lens_frames``; ``r2s_eval.twin.board_take.lens_take_plan``).
"""

from __future__ import annotations

from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.twin.board_take import record_board_take
from r2s_eval.twin.reality import load_reality_effects

READS = ("teleop.board_take", "calib.cameras.board", "world", "tasks", "seed")  # see _reads.py


def main(args) -> None:
    cfg = args.cfg
    record_board_take(args.out, load_world_params(args.twin), take=cfg["teleop.board_take"],
                      board_cfg=cfg["calib.cameras.board"], world=cfg["world"], tasks=cfg["tasks"], seed=cfg["seed"],
                      reality=load_reality_effects(args.twin))


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True, help="the twin's world parameters and reality effects")
    p.add_argument("--out", required=True, help="the take's dataset folder")
    _cli.run(main, p)
