"""Stage: score the camera calibration against the reality twin's truth (nothing downstream reads
it but the world report).

For each camera estimate (``METHOD=FILE``: calib_board's, calib_silhouette's) and for the model's
own poses, each camera's distance from the twin's true pose (position mm, rotation deg, in its
parent's frame); and, from the calibrated sim's world parameters, which estimate was used and
the appearance fit's colour error before and after (and, where it fitted, its light and each
object's colour against the twin's: ``r2s_eval.calib.cameras.look_errors``). An estimate that fitted the cameras' lenses
(``calib.cameras.board.intrinsics``) adds each lens against the twin's true lens, its reality
record's (``r2s_eval.twin.reality.load_reality_effects``: OpenCV's rational model; a twin without
one records through pinholes) (``r2s_eval.calib.cameras.lens_errors``: pixels at the take's image
size), and with a reality record the sim's shadows beside the twin's and the angle between their
key lights. Only this scoring reads the reality record, never the calibration. Writes::

    {"cameras": {"model" | METHOD: {camera: {"position_mm": .., "rotation_deg": ..}}},
     "used": METHOD | "none", "appearance": {"residual_before": .., "residual_after": ..
                                             [, "light_scale", "object_rgb_error"]
                                             [, "shadows", "twin_shadows", "key_light_deg"]}
     [, "background": {camera: {"with_plate", "without_plate", "frames" [, "shadows"]}}]
     [, "lens": {METHOD: {camera: {"distortion_px", "distortion_max_px", "model_px",
                                   "focal_pct": {"fx", "fy"}, "principal_point_px", "image_size"}}}]}
"""

from __future__ import annotations

from r2s_eval.calib.cameras import score_calibration
from r2s_eval.errors import DataError
from r2s_eval.report.calibration_report import camera_lines
from r2s_eval.sim import load_world_params
from r2s_eval.stages import _cli
from r2s_eval.twin.reality import load_reality_effects
from r2s_eval.utils.io import read_json, write_json

READS = ("world", "tasks")  # config paths the --cfg slice holds (see _reads.py)


def main(args) -> None:
    cfg = args.cfg
    estimates = {}
    for value in args.cameras:
        method, sep, path = value.partition("=")
        if not sep:
            raise DataError(f"--cameras {value!r}: expected METHOD=FILE")
        estimates[method] = read_json(path)
    reality = load_reality_effects(args.twin)
    report = score_calibration(estimates, read_json(args.world_params), load_world_params(args.twin), cfg["world"],
                               cfg["tasks"], true_lenses=None if reality is None else reality.lens_distortion,
                               true_shadows=None if reality is None else reality.shadows)
    print("\n".join(camera_lines(report)))
    write_json(args.out, report, provenance=True)


if __name__ == "__main__":
    p = _cli.parser(__doc__)
    p.add_argument("--twin", required=True, help="the twin's world parameters (its true cameras) and reality effects "
                                            "(its true lenses)")
    p.add_argument("--cameras", nargs="*", default=[], help="METHOD=FILE: a camera estimate to score")
    p.add_argument("--world-params", required=True, help="the calibrated sim's world parameters")
    p.add_argument("--out", required=True)
    _cli.run(main, p)
