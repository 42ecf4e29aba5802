"""The Python package anisocap: every call, bad input, the GIL, and equality with the program."""
import json
import signal
import sys
import threading
import time

import numpy as np
import pytest

import anisocap
from conftest import random_maps


def test_synthesize_gives_maps_configurations_and_their_renderings(material):
    maps, configs, photos = material["maps"], material["configurations"], material["photos"]
    assert maps.shape == (16, 24, 12) and maps.dtype == np.float32
    assert photos.shape == (6, 16, 24, 3) and photos.dtype == np.float32
    assert len(configs) == 6 and all(c.camera[2] > 0 and c.light[2] > 0 for c in configs)
    np.testing.assert_array_equal(anisocap.render(maps, configs), photos)
    other = anisocap.synthesize(width=24, height=16, images=6, seed=4)
    assert not np.array_equal(other["maps"], maps)


def test_maps_round_trip_through_files(material, tmp_path):
    anisocap.write_maps(material["maps"], tmp_path / "maps")
    assert (tmp_path / "maps" / "diffuse.exr").is_file() and (tmp_path / "maps" / "diffuse.png").is_file()
    np.testing.assert_allclose(anisocap.read_maps(tmp_path / "maps"), material["maps"], atol=1e-6)
    anisocap.write_maps(material["maps"], tmp_path / "plain", previews=False)
    assert not (tmp_path / "plain" / "diffuse.png").exists()


def test_capture_round_trips_through_files(material, tmp_path):
    configs = material["configurations"]
    masks = np.ones(material["photos"].shape[:3], np.float32)
    masks[:, :4, :] = 0
    for i, c in enumerate(configs):
        c.mask = f"mask_{i:02d}.png"
    anisocap.write_capture(configs, material["photos"], tmp_path, masks=masks)
    read = anisocap.read_capture(tmp_path / "capture.json")
    np.testing.assert_array_equal(read["photos"], material["photos"])
    np.testing.assert_array_equal(read["masks"], masks)
    for a, b in zip(read["configurations"], configs):
        assert a.camera == b.camera and a.light == b.light and a.intensity == b.intensity and a.file == b.file
    with pytest.raises(anisocap.FileError, match="nothing.json"):
        anisocap.read_capture(tmp_path / "nothing.json")


def test_render_features_and_precision(material):
    maps, configs = material["maps"], material["configurations"]
    full = anisocap.render(maps, configs)
    double = anisocap.render(maps, configs, precision="double")
    np.testing.assert_allclose(double, full, rtol=1e-4, atol=1e-6)
    # Without the normal map the kernel renders the maps with flat normals.
    flat_maps = maps.copy()
    flat_maps[..., 9:11] = 0
    np.testing.assert_allclose(anisocap.render(maps, configs, features="flat"), anisocap.render(flat_maps, configs),
                               rtol=1e-5, atol=1e-7)
    assert not np.allclose(anisocap.render(maps, configs, features="flat"), full)
    with pytest.raises(ValueError, match="kernel"):
        anisocap.render(maps, configs, features="shiny")


def test_loss_and_gradient_against_finite_differences(material):
    # Photographs the maps render brighter than on half of them and darker on the rest: no pixel at
    # the kink of |log R - log B|, where finite differences match no gradient.
    configs = material["configurations"]
    maps = random_maps(16, 24, seed=1)
    photos = anisocap.render(maps, configs) * np.array([1.6, 0.6] * 3, np.float32)[:, None, None, None]
    loss, grad = anisocap.loss_and_gradient(maps, configs, photos, precision="double")
    assert loss > 0 and grad.shape == maps.shape and grad.dtype == np.float32
    targets = anisocap.loss_targets(photos)
    assert anisocap.loss_and_gradient(maps, configs, targets, precision="double")[0] == loss
    assert anisocap.loss_and_gradient(maps, configs, targets, gradient=False)[1] is None
    for (y, x, k) in [(3, 5, 0), (7, 2, 4), (10, 20, 6), (1, 1, 8), (12, 9, 9), (4, 17, 11)]:
        h = 1e-3
        up, down = maps.copy(), maps.copy()
        up[y, x, k] += h
        down[y, x, k] -= h
        numeric = (anisocap.loss_and_gradient(up, configs, targets, precision="double", gradient=False)[0] -
                   anisocap.loss_and_gradient(down, configs, targets, precision="double", gradient=False)[0]) / (2 * h)
        assert grad[y, x, k] == pytest.approx(numeric, rel=2e-2, abs=1e-6)
    # The photographs' own maps fit them exactly.
    assert anisocap.loss_and_gradient(material["maps"], configs, material["photos"])[0] < 1e-5


def test_masks_leave_pixels_out_of_the_loss(material):
    configs, photos = material["configurations"], material["photos"]
    maps = random_maps(16, 24, seed=2)
    masks = np.ones(photos.shape[:3], np.float32)
    masks[:, :, :12] = 0
    _, grad = anisocap.loss_and_gradient(maps, configs, photos, masks=masks)
    assert np.all(grad[:, :12] == 0) and np.any(grad[:, 12:] != 0)


@pytest.mark.parametrize("bad, error, message", [
    (lambda m: m.astype(np.float64), TypeError, "float32"),
    (lambda m: m[..., :11], ValueError, "12 channels"),
    (lambda m: m[0], ValueError, "3 dimensions"),
    (lambda m: [[1.0]], TypeError, "numpy array"),
])
def test_bad_maps_are_refused_naming_the_argument(material, bad, error, message):
    with pytest.raises(error, match=message) as caught:
        anisocap.render(bad(material["maps"]), material["configurations"])
    assert "maps" in str(caught.value)


def test_nan_is_refused_naming_where(material):
    maps = material["maps"].copy()
    maps[2, 3, 7] = np.nan
    with pytest.raises(ValueError, match="maps: NaN or infinite value at row 2, column 3, channel 7"):
        anisocap.render(maps, material["configurations"])
    photos = material["photos"].copy()
    photos[1, 0, 0, 0] = np.inf
    with pytest.raises(ValueError, match=r"photos\[1\]: NaN"):
        anisocap.loss_and_gradient(material["maps"], material["configurations"], photos)


def test_photos_of_other_sizes_or_counts_are_refused(material, tmp_path):
    maps, configs, photos = material["maps"], material["configurations"], material["photos"]
    with pytest.raises(ValueError, match="configurations for"):
        anisocap.loss_and_gradient(maps, configs[:5], photos)
    with pytest.raises(ValueError, match="maps are 8 x 24"):
        anisocap.loss_and_gradient(maps[:8], configs, photos)
    with pytest.raises(ValueError, match=r"photos\[1\]: 16 x 23"):
        anisocap.loss_targets([photos[0], photos[1][:, :23]])
    with pytest.raises(ValueError, match="photographs for"):
        anisocap.capture(photos[:5], configs, models=False, steps=1)
    with pytest.raises(ValueError, match="photographs for"):
        anisocap.write_capture(configs, photos[:5], tmp_path)
    with pytest.raises(ValueError, match="masks for"):
        anisocap.write_capture(configs, photos, tmp_path, masks=np.ones((2,) + photos.shape[1:3], np.float32))
    assert not any(tmp_path.iterdir())


def test_non_contiguous_arrays_give_the_contiguous_result(material):
    maps, configs = material["maps"], material["configurations"]
    wide = np.zeros((16, 48, 12), np.float32)
    wide[:, ::2] = maps
    strided = wide[:, ::2]
    assert not strided.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(anisocap.render(strided, configs), anisocap.render(maps, configs))
    fortran = np.asfortranarray(maps)
    np.testing.assert_array_equal(anisocap.render(fortran, configs), anisocap.render(maps, configs))


def test_capture_refines_towards_the_truth(material):
    result = anisocap.capture(material["photos"], material["configurations"], models=False, steps=200)
    assert result["maps"].shape == (16, 24, 12) and not result["networks_ran"]
    assert [s["name"] for s in result["stages"] if s["ran"]] == ["first_guess", "refine"]
    start_loss = anisocap.loss_and_gradient(random_maps(16, 24), material["configurations"], material["photos"],
                                            gradient=False)[0]
    assert result["loss"] < 0.5 * start_loss
    with pytest.raises(ValueError, match="schedule"):
        anisocap.capture(material["photos"], material["configurations"], models=False, schedule="slow")
    with pytest.raises(ValueError, match="stages"):
        anisocap.capture(material["photos"], material["configurations"], models=False, stages="all")
    with pytest.raises(ValueError, match=r"estimate_stride \(65\) is larger than estimate_window \(64\)"):
        anisocap.capture(material["photos"], material["configurations"], models=False, estimate_window=64,
                         estimate_stride=65)


def test_capture_returns_the_uncertainty_calibrated_for_the_photographs_encoding(tmp_path):
    material = anisocap.synthesize(width=24, height=16, images=6, seed=3)
    anisocap.write_capture(material["configurations"], material["photos"], tmp_path)
    description = json.loads((tmp_path / "capture.json").read_text())
    description["images"][2]["encoding"] = "jpeg_subsampled"  # as rectify writes for a phone's JPEG
    (tmp_path / "capture.json").write_text(json.dumps(description))
    read = anisocap.read_capture(tmp_path / "capture.json")
    assert [c.encoding for c in read["configurations"]] == ["lossless"] * 2 + ["jpeg_subsampled"] + ["lossless"] * 3
    result = {}
    for name, configurations in (("lossless", material["configurations"]), ("jpeg_subsampled", read["configurations"])):
        result[name] = anisocap.capture(read["photos"], configurations, models=False, steps=50)
        u = result[name]["uncertainty"]
        assert u["calibration"] == name
        assert u["sd"].shape == result[name]["maps"].shape
        assert np.all(np.isfinite(u["sd"])) and np.all(u["sd"] > 0)
        # The remaining Gauss-Newton step: as the maps, and small against the deviations where
        # the refine settled at the photographs' fit (most texels).
        assert u["step"].shape == result[name]["maps"].shape and np.all(np.isfinite(u["step"]))
        assert np.median(np.abs(u["step"]) / u["sd"]) < 0.5
        assert set(u["determined_share"]) == {"a_d.r", "a_d.g", "a_d.b", "a_s.r", "a_s.g", "a_s.b", "sigma_x", "sigma_y", "F0",
                                              "n_x", "n_y", "alpha"}
        assert all(0 <= v <= 1 for v in u["determined_share"].values())
    # The same fit, the diffuse albedo's deviations wider for the subsampled colour.
    np.testing.assert_array_equal(result["lossless"]["maps"], result["jpeg_subsampled"]["maps"])
    assert np.mean(result["jpeg_subsampled"]["uncertainty"]["sd"][..., 0]) > np.mean(result["lossless"]["uncertainty"]["sd"][..., 0])
    with pytest.raises(ValueError, match="encoding: 'lossless', 'eight_bit', 'jpeg' or 'jpeg_subsampled', got 'png'"):
        anisocap.Configuration(encoding="png")


def test_capture_reports_progress_and_stops_when_the_callback_raises(material):
    heard = []

    def progress(stage, step, steps, loss):
        heard.append((stage, step, steps))
        if step >= 20:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        anisocap.capture(material["photos"], material["configurations"], models=False, steps=1000, progress=progress)
    assert heard and heard[-1][1] == 20 and heard[-1][2] == 1000


def test_ctrl_c_stops_a_capture(material):
    # A SIGINT arriving during the capture raises KeyboardInterrupt at the next progress report.
    timer = threading.Timer(0.3, signal.raise_signal, (signal.SIGINT,))
    timer.start()
    start = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        anisocap.capture(material["photos"], material["configurations"], models=False, steps=10 ** 6)
    assert time.monotonic() - start < 30
    timer.join()


def test_the_gil_is_released_during_a_capture():
    # Another thread runs Python while the capture runs. With the GIL held it would run only in the
    # moments the capture's progress report (after every refine step, some 5 ms on 256 x 256 texels)
    # lends it the GIL, which a switch interval of 0.1 ms keeps to a few percent.
    data = anisocap.synthesize(width=256, height=256, images=6, seed=5)
    done = threading.Event()
    span = {}

    def run():
        span["start"] = time.monotonic()
        anisocap.capture(data["photos"], data["configurations"], models=False, steps=100, refine_stop=0)
        span["end"] = time.monotonic()
        done.set()

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    try:
        t0 = time.monotonic()
        n = 0
        while time.monotonic() - t0 < 0.2:
            n += 1
        rate = n / 0.2
        thread = threading.Thread(target=run)
        thread.start()
        ticks = []
        while not done.is_set():
            ticks.append(time.monotonic())
        thread.join()
    finally:
        sys.setswitchinterval(interval)
    length = span["end"] - span["start"]
    assert length > 0.3, "the capture was too short to tell"
    inner = [t for t in ticks if span["start"] + 0.1 * length < t < span["end"] - 0.1 * length]
    # This thread shares the cores with two OpenMP threads (and whatever else runs): on two loaded
    # cores it keeps some 15% of its own rate; a call holding the GIL (a sort of a long list, in
    # the same measurement) leaves it none.
    assert len(inner) > 0.05 * rate * 0.8 * length, (len(inner), rate, length)


def test_models_folder_and_a_capture_with_the_networks(material, tmp_path):
    folder = anisocap.models_folder()
    assert folder is not None and anisocap._anisocap.has_weights(str(folder))
    result = anisocap.capture(material["photos"], material["configurations"], finetune_steps=3, steps=3,
                              second_run=False)
    assert result["networks_ran"]
    assert [s["name"] for s in result["stages"] if s["ran"]] == ["estimate", "encode", "finetune", "refine"]
    with pytest.raises(ValueError, match="network weights"):
        anisocap.capture(material["photos"], material["configurations"], models=tmp_path, stages="all")


def test_export_writes_each_format(material, tmp_path):
    anisocap.export(material["maps"], "gltf", tmp_path / "m.gltf")
    doc = json.loads((tmp_path / "m.gltf").read_text())
    assert doc["asset"]["version"] == "2.0" and len(doc["materials"]) == 1
    assert doc["images"] and all(image["uri"].startswith("data:image/png") or (tmp_path / image["uri"]).is_file()
                                 for image in doc["images"])
    anisocap.export(material["maps"], "mitsuba", tmp_path / "mitsuba")
    assert any((tmp_path / "mitsuba").iterdir())
    with pytest.raises(ValueError, match="format"):
        anisocap.export(material["maps"], "obj", tmp_path / "x")


def test_rectify_a_synthetic_photograph_set(tmp_path):
    # A fronto-parallel photograph of a uniform 40 x 24 mm sample with its corners given.
    photo = np.full((120, 200, 3), 0.25, np.float32)
    anisocap.write_capture([anisocap.Configuration(file="p.exr")], photo[None], tmp_path)
    desc = {"sample": {"width_mm": 40, "height_mm": 24}, "camera": {"focal_length_px": 400},
            "photos": [{"file": "p.exr", "corners": [[20, 12], [180, 12], [180, 108], [20, 108]],
                        "light": {"position_mm": [0, 0, 100]}}]}
    (tmp_path / "photos.json").write_text(json.dumps(desc))
    heard = []
    result = anisocap.rectify(tmp_path / "photos.json", out=tmp_path / "out", resolution=20,
                              progress=lambda line, done, total, _: heard.append((done, total)))
    assert result["photos"].shape == (1, 12, 20, 3) and result["masks"].shape == (1, 12, 20)
    np.testing.assert_allclose(result["photos"][0], 0.25, atol=1e-4)
    assert result["configurations"][0].camera[2] > 0 and result["configurations"][0].light[2] > 0
    assert heard == [(1, 1)]
    read = anisocap.read_capture(tmp_path / "out" / "capture.json")
    np.testing.assert_array_equal(read["photos"], result["photos"])
    with pytest.raises(OSError, match="missing.json"):
        anisocap.rectify(tmp_path / "missing.json")
    desc["photos"][0].pop("corners")
    (tmp_path / "photos.json").write_text(json.dumps(desc))
    with pytest.raises(ValueError, match="markers"):
        anisocap.rectify(tmp_path / "photos.json")


# ---- equal to the program on the same input -------------------------------------------------


def test_synthesize_and_render_equal_the_programs(program, tmp_path):
    program("synthesize", "-o", tmp_path / "syn", "--width", 24, "--height", 16, "--images", 6, "--seed", 3)
    mine = anisocap.synthesize(width=24, height=16, images=6, seed=3)
    np.testing.assert_array_equal(anisocap.read_maps(tmp_path / "syn" / "truth"), mine["maps"])
    read = anisocap.read_capture(tmp_path / "syn" / "capture.json")
    np.testing.assert_array_equal(read["photos"], mine["photos"])
    maps = random_maps(16, 24, seed=5)
    anisocap.write_maps(maps, tmp_path / "maps")
    program("render", "--maps", tmp_path / "maps", "--capture", tmp_path / "syn" / "capture.json", "-o", tmp_path / "r")
    (tmp_path / "r" / "capture.json").write_text((tmp_path / "syn" / "capture.json").read_text())
    theirs = anisocap.read_capture(tmp_path / "r" / "capture.json")["photos"]
    np.testing.assert_array_equal(anisocap.render(anisocap.read_maps(tmp_path / "maps"), read["configurations"]), theirs)


def test_capture_equals_the_programs(program, tmp_path):
    program("synthesize", "-o", tmp_path / "syn", "--width", 32, "--height", 32, "--images", 5, "--seed", 6)
    capture_json = tmp_path / "syn" / "capture.json"
    program("capture", capture_json, "-o", tmp_path / "refine", "--stages", "refine", "--steps", 40, "--no-view")
    mine = anisocap.capture(capture_json, stages="refine", steps=40)
    np.testing.assert_array_equal(mine["maps"], anisocap.read_maps(tmp_path / "refine"))
    program("capture", capture_json, "-o", tmp_path / "nets", "--stages", "all", "--estimate-window", 64,
            "--estimate-stride", 64, "--finetune-steps", 4, "--steps", 5, "--no-view")
    mine = anisocap.capture(capture_json, stages="all", estimate_window=64, estimate_stride=64, finetune_steps=4, steps=5)
    np.testing.assert_array_equal(mine["maps"], anisocap.read_maps(tmp_path / "nets"))
    report = json.loads((tmp_path / "nets" / "report.json").read_text())
    assert mine["loss"] == pytest.approx(report["loss"], rel=1e-12)


def test_network_precision_is_checked(material):
    with pytest.raises(ValueError, match=r"^network_precision: unknown precision 'fp16' \(expected fp32 or bf16\)"):
        anisocap.capture(material["photos"], material["configurations"], models=False, network_precision="fp16")
    if anisocap.has_bf16():
        result = anisocap.capture(material["photos"], material["configurations"], models=False, steps=50,
                                  network_precision="bf16")
        assert np.isfinite(result["loss"])
    else:
        with pytest.raises(ValueError, match="AVX-512 BF16"):
            anisocap.capture(material["photos"], material["configurations"], models=False, network_precision="bf16")
