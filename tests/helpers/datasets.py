"""A tiny synthetic bimanual LeRobotDataset for the policy tests.

Each episode has a target (a coloured square in the images at a random place); the state moves
smoothly towards a target pose that depends on where the square is, and the action is the next
state. Learning is therefore visible in a few steps (the action is a smooth function of state)
and the image carries the information that varies across episodes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

CAMERAS = (
    "observation.images.head_left",
    "observation.images.head_right",
    "observation.images.wrist_left",
    "observation.images.wrist_right",
)


def build_dataset(
    root: Path,
    repo_id: str = "test/synthetic_bimanual",
    n_episodes: int = 3,
    n_steps: int = 20,
    image_hw: tuple[int, int] = (32, 32),
    cameras: tuple[str, ...] = CAMERAS,
    seed: int = 0,
) -> Path:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    h, w = image_hw
    features = {
        "observation.state": {"dtype": "float32", "shape": (14,), "names": None},
        "action": {"dtype": "float32", "shape": (14,), "names": None},
    }
    for cam in cameras:
        features[cam] = {"dtype": "video", "shape": (h, w, 3), "names": ["height", "width", "channels"]}
    ds = LeRobotDataset.create(repo_id, fps=10, features=features, root=root, use_videos=True)
    rng = np.random.default_rng(seed)
    for _ in range(n_episodes):
        cx, cy = rng.uniform(0.25, 0.75, size=2)
        goal = np.concatenate([np.full(7, cx - 0.5), np.full(7, cy - 0.5)]).astype(np.float32)
        goal[6], goal[13] = 1.0, -1.0  # gripper commands
        state = rng.normal(0.0, 0.05, size=14).astype(np.float32)
        img = np.zeros((h, w, 3), dtype=np.uint8)
        img[..., 1] = 40
        r0, c0 = int(cy * (h - 6)), int(cx * (w - 6))
        img[r0 : r0 + 6, c0 : c0 + 6, 0] = 230
        for _t in range(n_steps):
            action = (state + 0.25 * (goal - state)).astype(np.float32)
            frame = {"observation.state": state.copy(), "action": action, "task": "pick the cube"}
            for cam in cameras:
                frame[cam] = img
            ds.add_frame(frame)
            state = action
        ds.save_episode()
    ds.finalize()
    return root
