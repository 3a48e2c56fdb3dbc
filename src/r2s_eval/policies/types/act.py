"""ACT (Action Chunking with Transformers), trained from scratch."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from r2s_eval.policies.interface import PolicyError
from r2s_eval.policies.types.registry import register
from r2s_eval.policies.types.from_scratch import ScratchType


@register
class ACT(ScratchType):
    name = "act"

    def config_class(self):
        from lerobot.policies.act.configuration_act import ACTConfig

        return ACTConfig

    def chunk_kwargs(self, cfg: dict, kwargs: dict) -> None:
        # Our runner takes whole chunks from predict_action_chunk; lerobot's n_action_steps only
        # sizes its own select_action queue, which the evaluation never uses: the whole chunk.
        kwargs.update(chunk_size=cfg["chunk_size"], n_action_steps=cfg["chunk_size"])
        kwargs.setdefault("optimizer_lr_backbone", cfg["lr"])

    def adapt_preprocessor(self, cfg: dict, preprocessor) -> None:
        if cfg["image_size"] is None:
            return
        # ACT has no resize option: lerobot's registered resize step, before normalisation
        # (it clamps to [0, 1]), so the saved pipeline reloads with stock lerobot.
        from lerobot.processor import ImageCropResizeProcessorStep, NormalizerProcessorStep

        at = next(i for i, s in enumerate(preprocessor.steps) if isinstance(s, NormalizerProcessorStep))
        preprocessor.steps.insert(at, ImageCropResizeProcessorStep(resize_size=tuple(cfg["image_size"])))

    def training_speedups(self, policy):
        return single_output_convolutions(policy.model.backbone)

    def prepare_for_batches(self, policy) -> None:
        # Batch norms folded into the convolutions before them: one pass over the activations
        # less per layer (ResNet18 at 32 px, 128 images on one CPU thread: 80 against 93 ms).
        policy.model.backbone = batch_norms_folded(policy.model.backbone)

    def predict(self, runner, slots, observations):
        batch = runner.preprocess(observations)
        with one_backbone_pass(runner.policy.model, [batch[k] for k in runner.policy.config.image_features]):
            return runner.policy.predict_action_chunk(batch)


@contextmanager
def one_backbone_pass(model, images: list) -> Iterator[None]:
    """Within it, ACT's per-camera backbone calls (one ResNet pass per camera, in
    `image_features` order) return slices of one pass over every camera's images: a convolution
    over cameras x rows images costs less per image than one per camera (ResNet18 at 32 px on one
    CPU thread: 0.65 against 0.92 ms an image at 128 against 32 images). An image sits at the same
    row of the pass whatever the other rows hold, so a slot's features still do not depend on them."""
    if len(images) < 2:
        yield
        return
    import torch

    backbone = model.backbone
    features = backbone(torch.cat(images))["feature_map"].split([len(i) for i in images])
    pending = list(zip(images, features, strict=True))

    def forward(image):
        source, feature = pending.pop(0)
        if image is not source:  # lerobot changed how ACT walks its cameras
            raise PolicyError("ACT called its backbone on other images than the cameras' in order")
        return {"feature_map": feature}

    backbone.forward = forward  # an instance attribute: nn.Module.__call__ looks it up first
    try:
        yield
    finally:
        del backbone.forward
    if pending:
        raise PolicyError(f"ACT used {len(images) - len(pending)} of its {len(images)} cameras' features")


def batch_norms_folded(backbone):
    """A copy of a torchvision ResNet `backbone` with each frozen batch norm folded into the
    convolution registered just before it (ResNet's conv1/bn1, conv2/bn2, downsample pairs),
    or `backbone` itself when the copy does not compute what it does (another architecture)."""
    import copy

    import torch
    from torch.nn.utils.fusion import fuse_conv_bn_weights
    from torchvision.ops.misc import FrozenBatchNorm2d

    folded = copy.deepcopy(backbone)
    for module in folded.modules():
        children = list(module.named_children())
        for (_, conv), (norm_name, norm) in zip(children, children[1:]):
            if not (isinstance(conv, torch.nn.Conv2d) and isinstance(norm, FrozenBatchNorm2d)
                    and conv.bias is None and conv.out_channels == norm.weight.numel()):
                continue
            conv.weight, conv.bias = fuse_conv_bn_weights(conv.weight, None, norm.running_mean, norm.running_var,
                                                          norm.eps, norm.weight, norm.bias)
            setattr(module, norm_name, torch.nn.Identity())
    device = next(backbone.parameters()).device
    probe = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(0)).to(device)
    with torch.no_grad():
        before, after = backbone(probe), folded(probe)
    if before.keys() != after.keys() or not all(
            torch.allclose(before[k], after[k], rtol=1e-4, atol=1e-4 * float(before[k].abs().max())) for k in before):
        return backbone
    return folded


@contextmanager
def single_output_convolutions(module) -> Iterator[None]:
    """Within it, every convolution of `module` whose output is one pixel (ResNet's last stage on
    a 32 px image: 1x1 maps) is computed as the matrix product it is, over the kernel taps that
    meet the image: the others only ever meet zero padding. oneDNN runs such a convolution over
    all nine taps and reorders its weights at every call; in training, the demo's ACT step's
    backward costs about half (benchmarks/bench_train_step.py: 158 against 79 CPU-ms, batch 16,
    one CPU thread). Same sums up to
    rounding; the gradients of the unused taps are zero either way."""
    import torch

    convs = [m for m in module.modules() if isinstance(m, torch.nn.Conv2d)]
    for conv in convs:
        conv.forward = _single_output_forward(conv)  # an instance attribute: __call__ finds it first
    try:
        yield
    finally:
        for conv in convs:
            del conv.forward


def _single_output_forward(conv):
    import torch.nn.functional as F

    stock = type(conv).forward.__get__(conv)
    simple = conv.groups == 1 and conv.dilation == (1, 1) and isinstance(conv.padding, tuple) \
        and conv.padding_mode == "zeros"

    def forward(x):
        (kh, kw), (sh, sw), (ph, pw) = conv.kernel_size, conv.stride, conv.padding
        h, w = x.shape[-2:]
        if not simple or (h + 2 * ph - kh) // sh != 0 or (w + 2 * pw - kw) // sw != 0:
            return stock(x)
        # The one output pixel sees input rows ky - ph for taps ky; those inside the image count.
        rows, cols = min(kh, h + ph) - ph, min(kw, w + pw) - pw
        taps = conv.weight[:, :, ph:ph + rows, pw:pw + cols]
        return F.linear(x[:, :, :rows, :cols].flatten(1), taps.flatten(1), conv.bias)[:, :, None, None]

    return forward
