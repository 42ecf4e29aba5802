"""anisocap.torch: the image loss as a torch.autograd.Function, checked with gradcheck and against
a plain PyTorch implementation of the same BRDF (studies/reference/ward_reference.py, written from
docs/method.md alone, differentiated by autograd)."""
import pathlib
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import anisocap  # noqa: E402
import anisocap.torch  # noqa: E402
from conftest import random_maps  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "studies" / "reference"))
import ward_reference  # noqa: E402


def reference_loss(maps, configurations, photos):
    """The image loss of an H x W x 12 tensor by ward_reference, with autograd."""
    named = {"diffuse": maps[..., 0:3], "specular": maps[..., 3:6], "sx": maps[..., 6], "sy": maps[..., 7],
             "f0": maps[..., 8], "nx": maps[..., 9], "ny": maps[..., 10], "alpha": maps[..., 11]}
    capture = [{"camera": c.camera, "light": c.light, "intensity": c.intensity} for c in configurations]
    rendered = ward_reference.render(torch, named, capture)
    return ward_reference.image_loss(torch, rendered, torch.as_tensor(photos, dtype=maps.dtype)), rendered


@pytest.fixture(scope="module")
def scene():
    """Six configurations, and photographs that the test maps render brighter than on half of them
    and darker on the rest: no pixel sits at the loss's kink |log R - log B| = 0 (finite differences
    across it would not match any gradient)."""
    configs = anisocap.synthesize(width=6, height=5, images=6, seed=11)["configurations"]
    rendered = anisocap.render(random_maps(5, 6, seed=3), configs)
    factors = np.array([1.6, 0.6, 1.6, 0.6, 1.6, 0.6], np.float32)[:, None, None, None]
    return configs, rendered * factors


def test_gradcheck_in_double_precision(scene):
    configs, photos = scene
    targets = anisocap.loss_targets(photos)
    # The library keeps maps in float32, so the double loss sees maps rounded to float32: a step of
    # 1e-3 keeps that rounding (about 3e-8) well below the finite differences' resolution.
    maps = torch.tensor(random_maps(5, 6, seed=3, dtype=np.float64), requires_grad=True)
    assert torch.autograd.gradcheck(lambda m: anisocap.torch.image_loss(m, configs, targets), (maps,),
                                    eps=1e-3, atol=1e-5, rtol=1e-3)


def test_the_gradcheck_sees_a_wrong_gradient(scene):
    configs, photos = scene
    targets = anisocap.loss_targets(photos)

    class Halved(anisocap.torch.ImageLossFunction):
        @staticmethod
        def backward(ctx, grad_output):
            grads = anisocap.torch.ImageLossFunction.backward(ctx, grad_output)
            return (0.5 * grads[0],) + grads[1:]

    maps = torch.tensor(random_maps(5, 6, seed=3, dtype=np.float64), requires_grad=True)
    with pytest.raises(torch.autograd.gradcheck.GradcheckError if hasattr(torch.autograd.gradcheck, "GradcheckError")
                       else RuntimeError):
        torch.autograd.gradcheck(lambda m: Halved.apply(m, configs, targets, "full", "double"), (maps,), eps=1e-3,
                                 atol=1e-5, rtol=1e-3)


def test_equals_plain_pytorch_in_single_precision():
    data = anisocap.synthesize(width=20, height=14, images=8, seed=12)
    configs, photos = data["configurations"], data["photos"]
    start = random_maps(14, 20, seed=4)
    ours = torch.tensor(start, requires_grad=True)
    loss = anisocap.torch.ImageLoss(configs, photos)(ours)
    loss.backward()
    theirs = torch.tensor(start, requires_grad=True)
    reference, rendered = reference_loss(theirs, configs, photos)
    reference.backward()
    assert loss.dtype == torch.float32
    assert loss.item() == pytest.approx(reference.item(), rel=1e-4)
    scale = theirs.grad.abs().max().item()
    assert torch.allclose(ours.grad, theirs.grad, rtol=1e-2, atol=1e-3 * scale)
    # The renderings agree too (the reference is also what the speed table times).
    np.testing.assert_allclose(anisocap.render(start, configs), rendered.detach().numpy(), rtol=1e-3, atol=1e-6)


def test_an_optimiser_fits_the_photographs():
    data = anisocap.synthesize(width=16, height=16, images=8, seed=13)
    loss_fn = anisocap.torch.ImageLoss(data["configurations"], data["photos"])
    maps = torch.tensor(random_maps(16, 16, seed=6), requires_grad=True)
    optimiser = torch.optim.Adam([maps], lr=1e-2)
    first = None
    for _ in range(60):
        optimiser.zero_grad()
        loss = loss_fn(maps)
        loss.backward()
        optimiser.step()
        first = first if first is not None else loss.item()
    assert loss.item() < 0.6 * first


def test_bad_tensors_are_refused(scene):
    configs, photos = scene
    with pytest.raises(ValueError, match="H x W x 12"):
        anisocap.torch.image_loss(torch.zeros(5, 6, 11), configs, photos)
    bad = torch.tensor(random_maps(5, 6, seed=3))
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        anisocap.torch.image_loss(bad, configs, photos)
