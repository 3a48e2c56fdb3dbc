"""Peer-protocol key maps: our observation streams under the keys, sizes and dtypes a server expects.

Our client sends our own stream names (`observation.images.<camera>`, `observation.state`,
`task`); openpi's servers read the keys of openpi's example clients. A server candidate's key map
names, for each key its server reads, the one stream of ours that fills it:

    preset: openpi_libero              # openpi's examples/libero client (or openpi_droid)
    keys:                              # entries given override the preset's, key by key
      observation/image: {camera: image, size: [224, 224], dtype: uint8}
      observation/state: {state: [0, 8], dtype: float64}
      prompt: {instruction: true}
      observation/wrist_image: null    # null: the server reads no such key (drops a preset key)

An entry names exactly one stream: `camera: <name>` (our `observation.images.<name>`, an HxWx3
uint8 image), `state: true` (the whole state) or `state: [start, stop]` (a slice of it), or
`instruction: true` (the task text). `size: [H, W]` resizes an image with padding, as openpi's
clients do (`openpi_client.image_tools.resize_with_pad`, bilinear; null: as rendered); `dtype` is
`uint8` for images, `float32` (default) or `float64` for the state. An entry given for a preset's
key keeps the preset's size and dtype unless it sets them; naming a stream, it replaces the
preset's. No map at all: requests carry our own names, as before.

Presets (`PRESETS`) are openpi's example clients: LIBERO (`examples/libero/main.py`: both images
224x224 uint8, the 8-D state as float64, 7-D actions back) and DROID (`examples/droid/main.py`:
exterior and wrist images 224x224 uint8, 7 joint positions and the gripper position as float64,
8-D actions back). The DROID preset cannot know which of a world's cameras is the exterior one and
which the wrist: its images need `camera` entries. Its state slices assume the Franka layout
(7 joints, then the gripper).

Every fault is a `PolicyError` naming the policy and the server key.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from r2s_eval.policies.interface import IMAGE_PREFIX, STATE_KEY, TASK_KEY, PolicyError

STREAMS = ("camera", "state", "instruction")
FIELDS = (*STREAMS, "size", "dtype")
DTYPES = ("uint8", "float32", "float64")
IMAGE_DTYPES = ("uint8",)
STATE_DTYPES = ("float32", "float64")
RESERVED = ("r2s_eval",)  # our server's reset message (r2s_eval.serving.policy_server.RESET_KEY)

_IMG = {"size": [224, 224], "dtype": "uint8"}
PRESETS: dict[str, dict] = {
    # openpi examples/libero/main.py: agent view and wrist view (turned 180 degrees, which
    # libero.observation.rotate_180 does), resize_with_pad to 224 + convert_to_uint8; the state is
    # eef position (3) + axis-angle (3) + gripper qpos (2) as float64 (robosuite's); (T, 7) back.
    "openpi_libero": {
        "action_dim": 7,
        "keys": {
            "observation/image": {"camera": "image", **_IMG},
            "observation/wrist_image": {"camera": "wrist_image", **_IMG},
            "observation/state": {"state": [0, 8], "dtype": "float64"},
            "prompt": {"instruction": True},
        },
    },
    # openpi examples/droid/main.py: resize_with_pad to 224 of an exterior camera and the wrist
    # camera; joint_position (7,) and gripper_position (1,) as float64; (T, 8) back (joint
    # velocities + gripper). Which of our cameras fills each image is the world's: no default.
    "openpi_droid": {
        "action_dim": 8,
        "keys": {
            "observation/exterior_image_1_left": dict(_IMG),
            "observation/wrist_image_left": dict(_IMG),
            "observation/joint_position": {"state": [0, 7], "dtype": "float64"},
            "observation/gripper_position": {"state": [7, 8], "dtype": "float64"},
            "prompt": {"instruction": True},
        },
    },
}


def resize_with_pad(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """An HxWx3 uint8 image scaled to fit (height, width), keeping its aspect, centred on zeros:
    openpi_client.image_tools.resize_with_pad (PIL, bilinear), pixel for pixel."""
    if image.shape[:2] == (height, width):
        return image
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(image))
    cur_width, cur_height = img.size
    ratio = max(cur_width / width, cur_height / height)
    resized_height, resized_width = int(cur_height / ratio), int(cur_width / ratio)
    resized = img.resize((resized_width, resized_height), resample=Image.BILINEAR)
    canvas = Image.new(resized.mode, (width, height), 0)
    canvas.paste(resized, (max(0, int((width - resized_width) / 2)), max(0, int((height - resized_height) / 2))))
    return np.asarray(canvas)


@dataclass(frozen=True)
class KeyEntry:
    """One key of the server's request and the stream of ours that fills it."""

    key: str
    camera: str | None = None
    state: tuple[int, int | None] | None = None  # (start, stop); stop None: to the end
    instruction: bool = False
    size: tuple[int, int] | None = None  # (H, W)
    dtype: str | None = None

    @property
    def stream(self) -> str:
        if self.camera is not None:
            return f"camera {self.camera!r}"
        if self.state is not None:
            return "the state" if self.state[1] is None else f"state[{self.state[0]}:{self.state[1]}]"
        return "the instruction"

    def to_dict(self) -> dict:
        if self.camera is not None:
            out: dict = {"camera": self.camera, **({"size": list(self.size)} if self.size else {})}
        elif self.state is not None:
            out = {"state": True if self.state == (0, None) else list(self.state)}
        else:
            out = {"instruction": True}
        if self.dtype is not None:
            out["dtype"] = self.dtype
        return out

    def fill(self, obs: Mapping):
        """This key's value from an observation that holds its stream (checked by `check_obs`)."""
        if self.camera is not None:
            img = np.asarray(obs[IMAGE_PREFIX + self.camera])
            if self.size is not None:
                img = resize_with_pad(img, *self.size)
            return np.ascontiguousarray(img, dtype=np.uint8)
        if self.state is not None:
            start, stop = self.state
            return np.ascontiguousarray(np.asarray(obs[STATE_KEY])[start:stop], dtype=self.dtype or "float32")
        return str(obs.get(TASK_KEY, ""))


@dataclass(frozen=True)
class KeyMap:
    """A server's request keys, each with the stream that fills it (see the module's text)."""

    entries: tuple[KeyEntry, ...]
    preset: str | None = None
    action_dim: int | None = None  # the preset's action width (the spec's `action_dim` wins)

    @property
    def cameras(self) -> tuple[str, ...]:
        """The observation keys of the cameras it reads (a policy spec's `cameras`)."""
        return tuple(dict.fromkeys(IMAGE_PREFIX + e.camera for e in self.entries if e.camera is not None))

    @property
    def uses_state(self) -> bool:
        return any(e.state is not None for e in self.entries)

    @property
    def uses_task(self) -> bool:
        return any(e.instruction for e in self.entries)

    @property
    def min_state_dim(self) -> int:
        return max((e.state[1] or 0 for e in self.entries if e.state is not None), default=0)

    def to_dict(self) -> dict:
        return {e.key: e.to_dict() for e in self.entries}

    def check_streams(self, cameras: Iterable[str] | None, state_dim: int | None, who: str,
                      offerer: str = "the world") -> None:
        """Raise naming the key when a key reads a camera not in `cameras` (names without the
        observation.images. prefix) or a state slice beyond `state_dim` (None: not known).
        `offerer`: who offers the streams, in words."""
        problems = []
        offered = None if cameras is None else sorted(cameras)
        for e in self.entries:
            if e.camera is not None and offered is not None and e.camera not in offered:
                problems.append(f"server key {e.key!r} reads camera {e.camera!r}, which {offerer} does not offer "
                                f"(cameras: {offered})")
            if e.state is not None and state_dim is not None and (e.state[1] or 0) > state_dim:
                problems.append(f"server key {e.key!r} reads {e.stream}, beyond the {state_dim}-D state")
        if problems:
            raise PolicyError(f"{who}: " + "; ".join(problems))

    def check_obs(self, obs: Mapping, who: str) -> None:
        """`check_streams` against what one observation holds."""
        cameras = [k.removeprefix(IMAGE_PREFIX) for k in obs if str(k).startswith(IMAGE_PREFIX)]
        if self.uses_state and STATE_KEY not in obs:
            raise PolicyError(f"{who}: server keys {[e.key for e in self.entries if e.state is not None]} read the "
                              f"state; the observation has none")
        state_dim = len(np.asarray(obs[STATE_KEY]).reshape(-1)) if self.uses_state else None
        self.check_streams(cameras, state_dim, who)

    def request(self, obs: Mapping) -> dict:
        """The message the server reads, in the map's key order (`obs` holds the streams: see
        `check_obs`)."""
        return {e.key: e.fill(obs) for e in self.entries}


def _entry(key: str, raw: Mapping, who: str, preset: str | None) -> KeyEntry:
    where = f"{who}: server key {key!r}"
    unknown = sorted(set(raw) - set(FIELDS))
    if unknown:
        raise PolicyError(f"{where} has unknown field(s) {unknown}; an entry takes {list(FIELDS)}")
    named = [s for s in STREAMS if raw.get(s) is not None]
    if not named:
        need = "camera" if raw.get("size") is not None or raw.get("dtype") in IMAGE_DTYPES else "stream"
        of = f" ('preset': {preset})" if preset else ""
        hint = (f"name the camera that fills it: 'keys': {{{key}: {{camera: <one of the world's cameras>}}}}"
                if need == "camera" else f"give it one of {list(STREAMS)}")
        raise PolicyError(f"{where}{of} is filled by nothing ({need} missing); {hint}")
    if len(named) > 1:
        raise PolicyError(f"{where} names {len(named)} streams ({' and '.join(named)}); it takes one")
    size, dtype = raw.get("size"), raw.get("dtype")
    if dtype is not None and dtype not in DTYPES:
        raise PolicyError(f"{where}: dtype must be one of {list(DTYPES)}, got {dtype!r}")
    kind = named[0]
    if kind != "camera" and size is not None:
        raise PolicyError(f"{where}: size is for images; it reads the {kind}")
    if kind == "camera":
        camera = raw["camera"]
        if not isinstance(camera, str) or not camera:
            raise PolicyError(f"{where}: camera must be a camera's name, got {camera!r}")
        if dtype is not None and dtype not in IMAGE_DTYPES:
            raise PolicyError(f"{where}: images travel as {' or '.join(IMAGE_DTYPES)}, not {dtype}")
        if size is not None:
            if (not isinstance(size, (list, tuple)) or len(size) != 2
                    or not all(type(n) is int and n > 0 for n in size)):
                raise PolicyError(f"{where}: size must be [height, width] in pixels, got {size!r}")
            size = (int(size[0]), int(size[1]))
        return KeyEntry(key, camera=camera.removeprefix(IMAGE_PREFIX), size=size, dtype=dtype)
    if kind == "state":
        value = raw["state"]
        if value is True:
            span: tuple[int, int | None] = (0, None)
        elif (isinstance(value, (list, tuple)) and len(value) == 2 and all(type(n) is int for n in value)
              and 0 <= value[0] < value[1]):
            span = (int(value[0]), int(value[1]))
        else:
            raise PolicyError(f"{where}: state must be true (all of it) or [start, stop] with 0 <= start < stop, "
                              f"got {value!r}")
        if dtype is not None and dtype not in STATE_DTYPES:
            raise PolicyError(f"{where}: the state travels as {' or '.join(STATE_DTYPES)}, not {dtype}")
        return KeyEntry(key, state=span, dtype=dtype)
    if raw["instruction"] is not True:
        raise PolicyError(f"{where}: instruction must be true, got {raw['instruction']!r}")
    if dtype is not None:
        raise PolicyError(f"{where}: the instruction travels as text; it takes no dtype")
    return KeyEntry(key, instruction=True)


def resolve_key_map(preset: str | None, keys: Mapping | None, who: str) -> KeyMap | None:
    """The key map of `preset` with `keys` laid over it; None when both are None (our own names).
    `who` ("policy 'name'") starts every error message."""
    if preset is None and keys is None:
        return None
    if preset is not None and preset not in PRESETS:
        raise PolicyError(f"{who}: 'preset' must be one of {sorted(PRESETS)}, got {preset!r}")
    if keys is not None and not isinstance(keys, Mapping):
        raise PolicyError(f"{who}: 'keys' must map each server key to its stream, got {keys!r}")
    base = PRESETS[preset] if preset is not None else {"keys": {}, "action_dim": None}
    merged: dict[str, dict] = copy.deepcopy(base["keys"])
    for key, given in (keys or {}).items():
        if not isinstance(key, str) or not key:
            raise PolicyError(f"{who}: 'keys' has the key {key!r}; server keys are non-empty strings")
        if key in RESERVED:
            raise PolicyError(f"{who}: 'keys' has {key!r}, which our client's reset message uses")
        if given is None:
            if key not in merged:
                of = f"preset {preset!r}'s keys {sorted(merged)}" if preset else "a preset's keys (no preset is set)"
                raise PolicyError(f"{who}: 'keys': {key}: null drops a preset key, and {key!r} is not one of {of}")
            del merged[key]
            continue
        if not isinstance(given, Mapping):
            raise PolicyError(f"{who}: server key {key!r} must map to its stream ({{camera: ...}}, {{state: ...}} or "
                              f"{{instruction: true}}), got {given!r}")
        entry = merged.get(key, {})
        if any(given.get(s) is not None for s in STREAMS):  # a stream named here replaces the preset's
            entry = {k: v for k, v in entry.items() if k not in STREAMS}
        merged[key] = {**entry, **dict(given)}
    if not merged:
        raise PolicyError(f"{who}: its key map leaves the server's request empty")
    entries, problems = [], []
    for key, raw in merged.items():  # every faulty key in one message
        try:
            entries.append(_entry(key, raw, who, preset if key in base["keys"] else None))
        except PolicyError as exc:
            problems.append(str(exc).removeprefix(f"{who}: "))
    if problems:
        raise PolicyError(f"{who}: " + "; ".join(problems))
    return KeyMap(tuple(entries), preset, base["action_dim"])
