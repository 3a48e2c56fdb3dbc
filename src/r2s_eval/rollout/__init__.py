"""Closed-loop policy rollouts: seeded initial configurations, episode loop, video.

``candidate`` (one candidate's resumable rollouts on one arm, written as one folder) loads the
policy sources, so it is imported from its module.
"""

from r2s_eval.rollout.episode_store import load_episodes
from r2s_eval.rollout.inits import sample_inits
from r2s_eval.rollout.loop import EpisodeResult, episode_id, run_episode, video_frame_every
from r2s_eval.rollout.mp4 import read_video, write_video

__all__ = ["EpisodeResult", "episode_id", "load_episodes", "read_video", "run_episode", "sample_inits", "video_frame_every", "write_video"]
