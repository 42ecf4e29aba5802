"""The renderer's image loss as a PyTorch function (needs PyTorch; ``import anisocap.torch``).

``image_loss(maps, configurations, targets)`` is the loss of docs/method.md section 5,
sum over images of the mean over pixels and channels of |log(R + 0.01) - log(B + 0.01)|, of an
``H x W x 12`` map tensor (the planes of ``anisocap.PARAMETERS``), with its gradient from the
library's fused renderer (no image is formed, and no autograd graph: the backward pass scales the
gradient the forward pass computed). It runs on the CPU; tensors elsewhere are copied there and
the gradient back. The maps are float32 in the library: float64 tensors evaluate the loss in double
arithmetic on the maps rounded to float32, which ``torch.autograd.gradcheck`` accepts with a
finite-difference step of about 1e-3 (tests/python/test_torch.py).

    import anisocap, anisocap.torch
    loss_fn = anisocap.torch.ImageLoss(configurations, photos)   # photos: N x H x W x 3
    maps = torch.tensor(start, requires_grad=True)                # H x W x 12
    opt = torch.optim.Adam([maps], lr=1e-2)
    for step in range(100):
        opt.zero_grad(); loss = loss_fn(maps); loss.backward(); opt.step()
"""
import torch

from . import _anisocap, loss_targets

__all__ = ["ImageLossFunction", "image_loss", "ImageLoss"]


class ImageLossFunction(torch.autograd.Function):
    """torch.autograd.Function: forward(maps, configurations, targets, features, precision) is
    the image loss as a 0-dimensional tensor of the maps' dtype; backward gives d(loss)/d(maps)."""

    @staticmethod
    def forward(ctx, maps, configurations, targets, features, precision):
        if maps.dim() != 3 or maps.shape[-1] != len(_anisocap.PARAMETERS):
            raise ValueError(f"maps: expected H x W x {len(_anisocap.PARAMETERS)}, got {tuple(maps.shape)}")
        array = maps.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()
        loss, gradient = _anisocap.loss_and_gradient(array, configurations, targets, features, precision, 0.0,
                                                     ctx.needs_input_grad[0])
        if gradient is not None:
            ctx.save_for_backward(torch.from_numpy(gradient).to(device=maps.device, dtype=maps.dtype))
        return torch.tensor(loss, dtype=maps.dtype, device=maps.device)

    @staticmethod
    def backward(ctx, grad_output):
        (gradient,) = ctx.saved_tensors
        return grad_output * gradient, None, None, None, None


def image_loss(maps, configurations, targets, features="full", precision=None):
    """The image loss of ``maps`` (H x W x 12 tensor) under ``configurations`` against
    ``targets`` (``anisocap.loss_targets(photos, masks)``, or the photographs themselves as an
    N x H x W x 3 array or tensor). ``features``: the BRDF terms (anisocap.render's names);
    ``precision``: float or double arithmetic (default: double for float64 maps)."""
    if not isinstance(targets, _anisocap.LossTargets):
        targets = loss_targets(_as_numpy(targets))
    if precision is None:
        precision = "double" if maps.dtype == torch.float64 else "float"
    return ImageLossFunction.apply(maps, list(configurations), targets, features, precision)


class ImageLoss(torch.nn.Module):
    """The image loss against fixed photographs, as a module: ``ImageLoss(configurations, photos,
    masks=None, floors=None, features="full")(maps)``. The photographs' side of the loss is
    computed once, here."""

    def __init__(self, configurations, photos, masks=None, floors=None, features="full"):
        super().__init__()
        self.configurations = list(configurations)
        self.targets = loss_targets(_as_numpy(photos), None if masks is None else _as_numpy(masks), floors)
        self.features = features

    def forward(self, maps, precision=None):
        return image_loss(maps, self.configurations, self.targets, self.features, precision)


def _as_numpy(images):
    """Float32 NumPy views of tensors (a list of them, or one N x ... tensor); arrays pass through."""
    if isinstance(images, torch.Tensor):
        return images.detach().to(device="cpu", dtype=torch.float32).numpy()
    if isinstance(images, (list, tuple)):
        return [_as_numpy(i) for i in images]
    return images
