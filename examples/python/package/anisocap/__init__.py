"""anisocap from Python: capture anisotropic Ward + Fresnel SVBRDF maps from photographs.

The calls are the C++ library's (docs/library.md), on NumPy arrays:

- a map set is an ``H x W x 12`` float32 array, the planes in the order of ``PARAMETERS``
  (diffuse RGB, specular RGB, lobe widths x and y, Fresnel F0, normal x and y, rotation);
- a photograph or a rendering is ``H x W x 3`` float32 (linear values), a mask ``H x W``
  (0: left out of the loss, up to 1: the pixel's weight); several are a list or an
  ``N x H x W x C`` array;
- a photograph's camera and light are a ``Configuration``; a capture is a list of them.

Arrays of another dtype raise TypeError, of another shape or holding NaN or infinite values
ValueError, naming the argument; the library's own checks raise ValueError (impossible options,
inputs that do not fit together) and ``FileError`` (an OSError: missing or unreadable files).
Every array is copied into the library's planar layout and back, whatever its strides.

Long calls (``render``, ``loss_and_gradient``, ``capture``, ``rectify``, ``synthesize``, the file
calls) release the GIL, so other Python threads run meanwhile. ``capture`` and ``rectify`` take a
``progress(stage, step, steps, loss)`` callback and stop, raising, on Ctrl-C or when the callback
raises. Threads: the kernels use OpenMP (``OMP_NUM_THREADS``).

``anisocap.torch`` (imported on its own, needs PyTorch) wraps the image loss as a
``torch.autograd.Function``.
"""
import os
import pathlib

from . import _anisocap
from ._anisocap import Configuration, LossTargets, FileError, CalibrationError, PARAMETERS, LOSS_EPSILON

__all__ = ["Configuration", "LossTargets", "FileError", "CalibrationError", "PARAMETERS", "LOSS_EPSILON",
           "read_maps", "write_maps", "read_capture", "write_capture", "render", "loss_targets",
           "loss_and_gradient", "synthesize", "capture", "export", "rectify", "models_folder", "has_bf16"]


def read_maps(folder):
    """The map set in ``folder`` (the EXR files ``anisocap capture`` writes) as an H x W x 12 array."""
    return _anisocap.read_maps(os.fspath(folder))


def write_maps(maps, folder, previews=True):
    """Writes ``maps`` (H x W x 12) into ``folder`` as EXR files, with PNG previews unless
    ``previews`` is False; all files appear together or none."""
    _anisocap.write_maps(maps, os.fspath(folder), previews)


def read_capture(file, saturation=0.0, exclude_clipped=True):
    """Reads a capture description (capture.json) and its photographs as ``anisocap capture``
    does. Returns a dict: ``configurations`` (list of Configuration, each with the ``encoding``
    of its file), ``photos`` (N x H x W x 3, exposure applied) and ``masks`` (N x H x W: the
    given masks, clipped pixels 0 unless ``exclude_clipped`` is False; ``saturation``: the linear
    level counting as clipped, 0: the format's largest code)."""
    return _anisocap.read_capture(os.fspath(file), saturation, exclude_clipped)


def write_capture(configurations, photos, folder, masks=None):
    """Writes ``photos`` as linear EXR files under their configurations' ``file`` names, ``masks``
    (optional) as 8-bit PNG under their ``mask`` names, and capture.json into ``folder``."""
    _anisocap.write_capture(list(configurations), photos, masks, os.fspath(folder))


def render(maps, configurations, features="full", precision="float"):
    """Renders ``maps`` under each configuration (docs/method.md section 4): N x H x W x 3.
    ``features``: the BRDF terms, full, isotropic, no-fresnel, flat, isotropic-flat or
    lambert-like; ``precision``: the arithmetic, float or double."""
    return _anisocap.render(maps, list(configurations), features, precision)


def loss_targets(photos, masks=None, floors=None):
    """Precomputes log(photo + 0.01), the masks and floors for ``loss_and_gradient``; reuse the
    result across calls on the same photographs."""
    return _anisocap.loss_targets(photos, masks, None if floors is None else [float(f) for f in floors])


def loss_and_gradient(maps, configurations, photos, masks=None, features="full", precision="float", cull=0.0,
                      gradient=True):
    """The image loss of ``maps`` against the photographs (docs/method.md section 5),
    sum over images of the mean over pixels and channels of |log(R + 0.01) - log(B + 0.01)|,
    and its gradient with respect to the maps (H x W x 12; None when ``gradient`` is False),
    from the fused renderer without forming any image. ``photos`` may be a ``LossTargets``
    (then ``masks`` must be None). ``cull``: the specular culling tolerance (0: exact)."""
    if isinstance(photos, LossTargets):
        if masks is not None:
            raise ValueError("masks: give them to loss_targets with the photographs")
        targets = photos
    else:
        targets = _anisocap.loss_targets(photos, masks, None)
    return _anisocap.loss_and_gradient(maps, list(configurations), targets, features, precision, cull, gradient)


def synthesize(width=256, height=256, images=12, set="alpha", seed=1, kind=None, mix="original", fresnel=2,
               shot_noise=0.0, read_noise=0.0):
    """A procedural material as ``anisocap synthesize`` makes it: a dict with ``maps`` (the true
    map set, canonical), ``configurations`` (set alpha or beta, docs/method.md section 6),
    ``photos`` (its renderings, with simulated sensor noise when asked) and ``kind``."""
    return _anisocap.synthesize(width, height, images, set, seed, kind or "", mix, fresnel, shot_noise, read_noise)


def has_bf16():
    """True when this build of the module can run the networks' convolutions in bf16
    (``capture(..., network_precision="bf16")``): built for a CPU with AVX-512 BF16."""
    return _anisocap.has_bf16()


def models_folder(preset="compact"):
    """The weights folder ``capture`` uses when given none, or None: in order ``$ANISOCAP_MODELS``,
    ``share/anisocap/models`` of the prefix the package is installed in, and the places the library
    searches (beside the program, the build tree's copy)."""
    places = []
    if os.environ.get("ANISOCAP_MODELS"):
        places.append(pathlib.Path(os.environ["ANISOCAP_MODELS"]))
    here = pathlib.Path(__file__).resolve().parent
    places += [p / "share" / "anisocap" / "models" for p in here.parents]
    places += [pathlib.Path(p) for p in _anisocap.models_search_path()]
    for place in places:
        if _anisocap.has_weights(os.fspath(place), preset):
            return place
    return None


def capture(photos, configurations=None, masks=None, *, models=None, preset="compact", also_models=None,
            stages="auto", schedule="fast", estimate_window=None, estimate_stride=None, finetune_steps=None,
            finetune_lr=None, steps=None, lr=None, refine_stop=None, neighbour_restarts=None, kernel="auto", precision="float",
            network_precision="fp32", second_run=None, start=None, progress=None, log=None):
    """Captures the map set of a material as ``anisocap capture`` does (docs/library.md,
    capture_material), with the program's options as keywords.

    ``photos``: N x H x W x 3 linear photographs with their ``configurations`` and optional
    ``masks``, or the path of a capture.json (read as ``read_capture`` does). ``models``: the
    weights folder (default: ``models_folder(preset)``; False: no networks, the refine alone).
    ``also_models``: the second prior's folder (default: the weights folder's also/; False: none).
    ``stages``: auto (the networks where their weights are found, else the refine alone), all, or a
    list such as "estimate,encode,finetune,refine". ``schedule``: fast, thorough or paper; the
    other keywords override it as the program's options of the same name do (``steps``, ``lr``
    and ``refine_stop`` are the refine's: its steps, learning rate, and the fraction by which 50
    steps must improve the loss for it to go on, 0: never stop early; ``neighbour_restarts`` a
    list of radii; ``second_run`` turns both second runs on or off; ``network_precision`` is the
    program's --network-precision: fp32, or bf16 where ``has_bf16()``). ``start``: maps to refine from instead of the network stages. ``progress``:
    called as progress(stage, step, steps, loss) after every window of the estimate and every step
    of the fine-tune and the refine; ``log``: called with each choice in words. Ctrl-C, or an
    exception the callback raises, stops the capture with that exception.

    Returns a dict: ``maps`` (H x W x 12, canonical), ``loss`` (the final image loss),
    ``stages`` (name, ran, steps, loss, seconds of each), ``networks_ran``, ``networks``,
    ``kernel``, ``exposure_scale`` and ``uncertainty``: ``sd`` (H x W x 12, each parameter's
    standard deviation per texel), ``noise``, ``determined_share`` (per parameter, the share of
    texels the photographs determine it on) and ``calibration`` (the photographs' encoding whose
    table applied, from each Configuration's ``encoding``).
    """
    if isinstance(photos, (str, os.PathLike)):
        if configurations is not None or masks is not None:
            raise ValueError("photos: a capture.json path brings its own configurations and masks")
        read = read_capture(photos)
        photos, configurations, masks = read["photos"], read["configurations"], read["masks"]
    if configurations is None:
        raise ValueError("configurations: one Configuration per photograph")
    if models is False:
        models_path = ""
    elif models is None:
        found = models_folder(preset)
        models_path = None if found is None else os.fspath(found)
    else:
        models_path = os.fspath(models)
    also = None if also_models is None else ("" if also_models is False else os.fspath(also_models))
    return _anisocap.capture(photos, list(configurations), masks, models_path, preset, also, stages, schedule,
                             estimate_window, estimate_stride, finetune_steps, finetune_lr, steps, lr, refine_stop,
                             None if neighbour_restarts is None else list(neighbour_restarts), kernel, precision,
                             network_precision, second_run, start, progress, log)


def export(maps, format, out, width=0.0):
    """Exports ``maps`` for a renderer: format gltf (``out`` a .gltf file), mitsuba, blender or
    mtlx (``out`` a folder); ``width``: the sample's width in metres for glTF (0: longest side 1)."""
    _anisocap.export(maps, format, os.fspath(out), width)


def rectify(photos_json, out=None, resolution=0, saturation=0.0, floor=0.005, margin_px=1.0, footprint="auto",
            dark_level=0.01, full_confidence_px=2.5, tag_mm=0.0, gap_mm=3.0, progress=None):
    """Perspective photographs of a flat sample (photos.json, as for ``anisocap rectify``) to a
    texture-space capture: a dict with ``configurations``, ``photos`` (N x H x W x 3) and ``masks``
    (the texels' weights in the loss). Written into ``out`` (rectified EXRs, masks, capture.json)
    when given. Photos without corners are located by the printed marker frame (``tag_mm``,
    ``gap_mm`` as given to ``anisocap markers``). ``progress(line, done, total, 0.0)`` hears
    after each photo."""
    return _anisocap.rectify(os.fspath(photos_json), None if out is None else os.fspath(out), resolution, saturation,
                             floor, margin_px, footprint, dark_level, full_confidence_px, tag_mm, gap_mm, progress)
