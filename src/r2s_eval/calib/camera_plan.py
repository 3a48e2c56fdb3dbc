"""Which camera estimates a run makes and which one its calibrated sim uses (``calib.cameras``),
decided once from the config and the world, for the workflow and the configuration check."""

from __future__ import annotations

from collections.abc import Mapping


def silhouette_possible(robot, segmenter_type: str) -> bool:
    """Whether the world says how its robot looks to the configured segmenter (``robot.find``)."""
    return robot.find_hue is not None if segmenter_type == "hsv" else True


def camera_plan(cameras_cfg: Mapping, robot, has_take: bool, segmenter_type: str) -> tuple[str, list[str]]:
    """Which camera estimate the calibrated sim uses (board, silhouette or none) and which are made
    (``calib.cameras``): ``use: auto`` is the board when there is a take (the twin's, or
    ``board_take``), else the silhouette when the world says how its robot looks, else none; the
    board estimate is made whenever there is a take, the silhouette's when used or when
    ``silhouette.fit`` is true (``auto``: when the world says how its robot looks), to compare."""
    possible = silhouette_possible(robot, segmenter_type)
    use = cameras_cfg["use"]
    if use == "auto":
        use = "board" if has_take else "silhouette" if possible else "none"
    fit = cameras_cfg["silhouette"]["fit"]
    made = (["board"] if has_take else []) + (
        ["silhouette"] if use == "silhouette" or fit is True or (fit == "auto" and possible) else [])
    return use, made
