"""Camera images of the kitchen scene, fast on a CPU-only machine (the one image path for data and envs).

Uses `mujoco.Renderer` directly with anti-aliasing, shadows, reflections and the skybox off and an offscreen buffer
no larger than needed; it returns images upright (row 0 = top), so no flip is needed anywhere else.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lerobot_skillret.kitchen.observations import CAMERAS

_CAMERA_IDS = {"agentview": "agentview", "eye_in_hand": "robot0_eye_in_hand"}
_OFF_FLAGS = (  # off for speed (see above)
    mujoco.mjtRndFlag.mjRND_SHADOW,
    mujoco.mjtRndFlag.mjRND_REFLECTION,
    mujoco.mjtRndFlag.mjRND_SKYBOX,
)


class CameraRenderer:
    def __init__(self, scene, size: int):
        model = scene.sim.model._model
        model.vis.quality.offsamples = 0
        model.vis.global_.offwidth = max(size, 64)
        model.vis.global_.offheight = max(size, 64)
        self.scene, self.size = scene, size
        self.renderer = mujoco.Renderer(model, height=size, width=size)

    def render(self, camera: str) -> np.ndarray:
        """(size, size, 3) uint8 image from `camera` ("agentview", "eye_in_hand" or any MJCF camera name)."""
        name = _CAMERA_IDS.get(camera, camera)
        if mujoco.mj_name2id(self.scene.sim.model._model, mujoco.mjtObj.mjOBJ_CAMERA, name) < 0:
            raise ValueError(f"unknown camera {camera!r}; the observation cameras are {CAMERAS}")
        self.renderer.update_scene(self.scene.sim.data._data, camera=name)
        for flag in _OFF_FLAGS:  # the only place they are set: right before each render
            self.renderer.scene.flags[flag] = False
        return self.renderer.render().copy()

    def close(self) -> None:
        self.renderer.close()
