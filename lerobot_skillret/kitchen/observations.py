"""The observation layout: ONE definition used by the data generators, the gym env and the EnvConfig.

- `agent_pos` / `observation.state` (9): eef position (3), eef orientation quaternion (w, x, y, z) with w >= 0
  (4), the two finger joint positions (2).
- `environment_state` / `observation.environment_state` (80): for every movable (layout.MOVABLES order) its
  position (3) and quaternion (w, x, y, z) (4), then the drawer slide, light switch and burner switch joints.
- `pixels/<camera>` / `observation.images.<camera>` (H, W, 3) uint8, optional: "agentview", "eye_in_hand".
Import-light (numpy and this package; scipy only once a scene is observed) so the EnvConfig can derive its
features here without robosuite.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lerobot_skillret.data.labels import PRIMITIVE_KEY
from lerobot_skillret.files import read_json
from lerobot_skillret.kitchen import layout

CAMERAS = ("agentview", "eye_in_hand")
DEFAULT_IMAGE_SIZE = 84
# The fixtures' MuJoCo joints (scene.py reads and resets them), the last entries of `environment_state`.
FIXTURE_JOINTS = ("drawer_slide", "light_switch_joint", "burner_switch_joint")
STATE_NAMES = ["eef_x", "eef_y", "eef_z", "eef_qw", "eef_qx", "eef_qy", "eef_qz", "finger_left", "finger_right"]
ENV_STATE_NAMES = [f"{obj}_{c}" for obj in layout.MOVABLES for c in ("x", "y", "z", "qw", "qx", "qy", "qz")] + list(
    FIXTURE_JOINTS
)
ACTION_NAMES = ["dx", "dy", "dz", "dax", "day", "daz", "gripper"]
# env observation key -> LeRobot dataset / policy feature key
ENV_TO_DATASET = {"agent_pos": "observation.state", "environment_state": "observation.environment_state"}
KITCHEN_META = "meta/kitchen.json"  # per dataset: frames per primitive, episode seeds, tasks and initial states


def image_key(camera: str) -> str:
    return f"observation.images.{camera}"


def check_cameras(cameras) -> tuple[str, ...]:
    cameras = (cameras,) if isinstance(cameras, str) else tuple(cameras)  # `--env.cameras=agentview`: one camera
    unknown = [c for c in cameras if c not in CAMERAS]
    if unknown:
        raise ValueError(f"unknown camera(s) {unknown}; choose from {CAMERAS}")
    return cameras


def agent_pos(scene) -> np.ndarray:
    # Imported here, not at the top: a scene means robosuite (which imports scipy) is loaded already, and the
    # EnvConfig imports this module at plugin registration without a scene.
    from scipy.spatial.transform import Rotation

    quat = Rotation.from_matrix(scene.eef_mat()).as_quat(canonical=True, scalar_first=True)  # (w, x, y, z), w >= 0
    return np.concatenate([scene.eef_pos(), quat, scene.gripper_qpos()]).astype(np.float32)


def environment_state(scene) -> np.ndarray:
    parts = []
    for name in layout.MOVABLES:
        q = scene.body_quat(name)
        parts += [scene.body_pos(name), q if q[0] >= 0 else -q]
    parts.append(np.array([scene.joint(j) for j in FIXTURE_JOINTS]))
    return np.concatenate(parts).astype(np.float32)


def build_observation(scene, renderer=None, cameras: tuple[str, ...] = ()) -> dict:
    """The env-side observation dict (`agent_pos`, `environment_state`, optional `pixels`)."""
    obs = {"agent_pos": agent_pos(scene), "environment_state": environment_state(scene)}
    if cameras:
        obs["pixels"] = {cam: renderer.render(cam) for cam in cameras}
    return obs


def to_dataset_frame(obs: dict) -> dict:
    """Rename an env observation to LeRobot dataset keys."""
    frame = {ENV_TO_DATASET[k]: v for k, v in obs.items() if k in ENV_TO_DATASET}
    for cam, img in obs.get("pixels", {}).items():
        frame[image_key(cam)] = img
    return frame


def dataset_features(cameras: tuple[str, ...] = (), image_size: int = DEFAULT_IMAGE_SIZE) -> dict:
    """Feature spec for `LeRobotDataset.create` (plus the primitive label column)."""
    features = {
        "observation.state": {"dtype": "float32", "shape": (len(STATE_NAMES),), "names": STATE_NAMES},
        "observation.environment_state": {
            "dtype": "float32",
            "shape": (len(ENV_STATE_NAMES),),
            "names": ENV_STATE_NAMES,
        },
        "action": {"dtype": "float32", "shape": (len(ACTION_NAMES),), "names": ACTION_NAMES},
        PRIMITIVE_KEY: {"dtype": "int64", "shape": (1,), "names": None},
    }
    for cam in check_cameras(cameras):
        features[image_key(cam)] = {
            "dtype": "video",
            "shape": (image_size, image_size, 3),
            "names": ["height", "width", "channels"],
        }
    return features


def env_feature_shapes(cameras: tuple[str, ...] = (), image_size: int = DEFAULT_IMAGE_SIZE) -> dict:
    """Env-side keys -> shapes (`pixels/<cam>` for cameras), as the gym env and the EnvConfig declare them."""
    shapes = {"agent_pos": (len(STATE_NAMES),), "environment_state": (len(ENV_STATE_NAMES),)}
    for cam in check_cameras(cameras):
        shapes[f"pixels/{cam}"] = (image_size, image_size, 3)
    return shapes


def load_kitchen_meta(root: str | Path) -> dict:
    """The generator's side file of a dataset root (frames per primitive, per-episode seeds and initial states, ...)."""
    path = Path(root) / KITCHEN_META
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: {root} was not written by `skillret-generate` (only kitchen datasets have it)."
        )
    return read_json(path)
