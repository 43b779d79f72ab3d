"""Building blocks shared by every skillret module: MLPs, the observation encoder (LeRobot's spatial softmax).

The seed (C.1) gives each of the four observation-taking modules (skill encoder, decoder, prior, policy) its own
observation encoder: an MLP for the low-dimensional inputs and, per camera, a ResNet (18 in the seed) trained from
scratch whose feature map is pooled to keypoints by a spatial softmax, with random-crop augmentation during training.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping, Sequence

import torch
import torchvision
from lerobot.policies.diffusion.modeling_diffusion import SpatialSoftmax
from lerobot.policies.utils import get_output_shape
from torch import Tensor, nn


def mlp(in_dim: int, hidden: Sequence[int], out_dim: int | None = None) -> nn.Sequential:
    """Linear+ReLU layers of widths `hidden`, then an optional linear output layer (no activation)."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), nn.ReLU()]
        in_dim = width
    if out_dim is not None:
        layers.append(nn.Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


def mlp_out_dim(in_dim: int, hidden: Sequence[int], out_dim: int | None = None) -> int:
    """Width of what `mlp(in_dim, hidden, out_dim)` returns."""
    if out_dim is not None:
        return out_dim
    return hidden[-1] if hidden else in_dim


def random_crop(images: Tensor, size: tuple[int, int], generator: torch.Generator | None = None) -> Tensor:
    """An independent random (h, w) crop of each image in (N, C, H, W)."""
    n, _, height, width = images.shape
    ch, cw = size
    top = torch.randint(0, height - ch + 1, (n,), device=images.device, generator=generator)
    left = torch.randint(0, width - cw + 1, (n,), device=images.device, generator=generator)
    rows = (top[:, None] + torch.arange(ch, device=images.device))[:, None, :, None]  # (N, 1, ch, 1)
    cols = (left[:, None] + torch.arange(cw, device=images.device))[:, None, None, :]  # (N, 1, 1, cw)
    batch = torch.arange(n, device=images.device)[:, None, None, None]
    channels = torch.arange(images.shape[1], device=images.device)[None, :, None, None]
    return images[batch, channels, rows, cols]


def center_crop(images: Tensor, size: tuple[int, int]) -> Tensor:
    height, width = images.shape[-2:]
    top, left = (height - size[0]) // 2, (width - size[1]) // 2
    return images[..., top : top + size[0], left : left + size[1]]


class CameraEncoder(nn.Module):
    """One camera: crop -> ResNet trunk (no ImageNet weights, as in the seed) -> spatial softmax keypoints."""

    def __init__(
        self,
        image_shape: Sequence[int],
        crop_shape: tuple[int, int] | None,
        num_keypoints: int,
        backbone: str,
    ) -> None:
        super().__init__()
        channels, height, width = image_shape
        self.crop_shape = tuple(crop_shape) if crop_shape is not None else None
        resnet = getattr(torchvision.models, backbone)(weights=None)  # a name from configuration's RESNETS
        if channels != 3:
            resnet.conv1 = nn.Conv2d(channels, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.trunk = nn.Sequential(*list(resnet.children())[:-2])  # drop average pooling and the classifier
        in_h, in_w = self.crop_shape or (height, width)
        # probe in eval mode: batch norm cannot train on one 1x1 feature map
        feature_shape = get_output_shape(self.trunk.eval(), (1, channels, in_h, in_w))
        self.trunk.train()
        if feature_shape[2] * feature_shape[3] == 1:
            logging.warning(
                "skillret: camera images of %sx%s leave a 1x1 ResNet feature map; its spatial softmax carries no "
                "image information. Use images of at least 64x64 (the seed crops 76x76 from 84x84).",
                in_h,
                in_w,
            )
        # LeRobot's (Diffusion Policy's) spatial softmax: K learned heat maps -> their expected (x, y) in [-1, 1];
        # it keeps *where* things are, which average pooling throws away
        self.pool = SpatialSoftmax(feature_shape[1:], num_kp=num_keypoints)
        self.out_dim = 2 * num_keypoints

    def forward(self, images: Tensor) -> Tensor:
        """(N, C, H, W) floats in [0, 1] -> (N, 2K)."""
        if self.crop_shape is not None:
            images = random_crop(images, self.crop_shape) if self.training else center_crop(images, self.crop_shape)
        return self.pool(self.trunk(images)).flatten(1)  # (N, K, 2) -> (N, 2K)


class ObservationEncoder(nn.Module):
    """Observation dict of (B, T, ...) tensors -> (B, T, out_dim): low-dim MLP and camera keypoints, concatenated.

    `low_dim_keys` are concatenated in the given order (one order for every module), cameras follow.
    """

    def __init__(
        self,
        low_dim_shapes: Mapping[str, Sequence[int]],
        image_shapes: Mapping[str, Sequence[int]],
        low_dim_mlp: Sequence[int],
        crop_shape: tuple[int, int] | None,
        num_keypoints: int,
        backbone: str,
    ) -> None:
        super().__init__()
        self.low_dim_keys = list(low_dim_shapes)
        self.image_keys = list(image_shapes)
        low_dim = sum(int(shape[0]) for shape in low_dim_shapes.values())
        self.low_dim_net = mlp(low_dim, low_dim_mlp) if self.low_dim_keys else None
        self.cameras = nn.ModuleList(
            CameraEncoder(shape, crop_shape, num_keypoints, backbone) for shape in image_shapes.values()
        )
        self.out_dim = (mlp_out_dim(low_dim, low_dim_mlp) if self.low_dim_keys else 0) + sum(
            camera.out_dim for camera in self.cameras
        )

    def forward(self, observation: Mapping[str, Tensor]) -> Tensor:
        parts = []
        if self.low_dim_net is not None:
            parts.append(self.low_dim_net(torch.cat([observation[key] for key in self.low_dim_keys], dim=-1)))
        for key, camera in zip(self.image_keys, self.cameras, strict=True):
            images = observation[key]
            lead = images.shape[:-3]
            parts.append(camera(images.reshape(-1, *images.shape[-3:])).reshape(*lead, camera.out_dim))
        return parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)


CellState = list[tuple[Tensor, Tensor]]
LSTMState = tuple[Tensor, Tensor]


@functools.cache
def _onednn_runs_bf16() -> bool:
    """Whether oneDNN has bfloat16 kernels on this CPU (AVX-512 and newer): CPU autocast hands `nn.LSTM` to oneDNN,
    which fails without them ("could not create a primitive descriptor for the LSTM forward propagation primitive").
    torch has no public query for it."""
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def run_lstm(lstm: nn.LSTM, inputs: Tensor, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
    """`lstm(inputs, state)`; in float32 under CPU autocast on a CPU without oneDNN's bfloat16 kernels, so that
    `--policy.use_amp=true` trains everywhere (the LSTMs then run at float32 speed, the rest in bfloat16)."""
    if inputs.device.type == "cpu" and torch.is_autocast_enabled("cpu") and not _onednn_runs_bf16():
        with torch.autocast("cpu", enabled=False):
            state = None if state is None else (state[0].float(), state[1].float())
            return lstm(inputs.float(), state)
    return lstm(inputs, state)


def lstm_steps(lstm: nn.LSTM, inputs: Tensor, state: CellState | None = None) -> tuple[Tensor, CellState]:
    """Run a (batch_first) `nn.LSTM`'s weights step by step with `torch.lstm_cell`: inputs (B, T, D) -> the last
    step's output (B, hidden) and the per-layer (h, c) state.

    Why: on CPU one `nn.LSTM` call costs ~1 ms of fixed overhead even for one step, ~4x a cell loop, and the
    decoder runs one step per environment step. For whole sequences (training, the policy's F-step history every
    H steps) `nn.LSTM` is the faster one."""
    if state is None:
        zeros = inputs.new_zeros(inputs.shape[0], lstm.hidden_size)
        state = [(zeros, zeros)] * lstm.num_layers
    weights = [
        tuple(getattr(lstm, f"{name}_l{layer}") for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh"))
        for layer in range(lstm.num_layers)
    ]
    for t in range(inputs.shape[1]):
        layer_input, new_state = inputs[:, t], []
        for (h, c), (w_ih, w_hh, b_ih, b_hh) in zip(state, weights, strict=True):
            h, c = torch.lstm_cell(layer_input, (h, c), w_ih, w_hh, b_ih, b_hh)
            new_state.append((h, c))
            layer_input = h
        state = new_state
    return state[-1][0], state
