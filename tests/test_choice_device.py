"""``auto`` decides from the choice data of the device in use (bdipole_cl/methods/choice.py):
a calibration of this device when there is one, never another device's, else the shipped
data with a note; ``bdipole-cl report --calibrate`` writes what ``auto`` then reads."""
import json
import logging
from types import SimpleNamespace

import numpy as np
import pyopencl as cl
import pytest

from bdipole_cl import blur, invert_albedo
from bdipole_cl.apps.report import calibrate
from bdipole_cl.device import Runtime
from bdipole_cl.methods import choice
from bdipole_cl.methods.choice import ChoiceData, DeviceKey, calibration_path, write_choice_data
from bdipole_cl.methods.registry import BlurChoice, InversionChoice, MethodConfig
from bdipole_cl.ops.blur.planning import auto_data


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    """An empty calibration folder of this test's own, and no named choice data."""
    monkeypatch.setenv(choice.CACHE_DIR_VARIABLE, str(tmp_path / "cache"))
    monkeypatch.delenv(choice.CHOICE_DATA_VARIABLE, raising=False)
    monkeypatch.setattr(choice, "_noted", set())
    return tmp_path / "cache"


def foreign_data(key):
    """Data that, if used, would make auto pick table(size=8) and blur with gaussians."""
    inv = (InversionChoice(MethodConfig("table", table_size=8, polish=0), "f32", 1e-9, 1e-9,
                           True, (1.4,)),)
    return ChoiceData("some GPU", inv, (BlurChoice("gaussians", 1e-3, 4, 1.0, 1e-9, 1e-9),), key)


def test_calibration_path_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.delenv(choice.CACHE_DIR_VARIABLE, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    key = DeviceKey("Vendor", "Dev 1", "3.0")
    path = calibration_path(key)
    assert path.parent == tmp_path / "bdipole_cl" and path.name.startswith("choice-vendor-dev-1")
    assert calibration_path(DeviceKey("Vendor", "Dev 1", "3.1")) != path    # a new driver


def test_data_for_another_device_are_not_used(on_device, cache_dir, caplog):
    """Another device's calibration, even stored under this device's file name, is not used
    here: auto falls back to the shipped data and says so where a user looks (BlurInfo, the
    source's description), not as a warning on every command's stderr."""
    here = DeviceKey.of(on_device.device)
    other = DeviceKey("Other Vendor", "Some GPU", "1.0")
    write_choice_data(foreign_data(other), calibration_path(other))
    write_choice_data(foreign_data(other), calibration_path(here))     # wrong key inside
    with caplog.at_level(logging.INFO, logger="bdipole_cl"):
        data, source = choice.choice_for(here)
        choice.choice_for(here)
        invert_albedo(np.float32([0.5]), 1.4, "auto")
    assert source.kind == "shipped" and not source.this_device, source
    assert data.device != "some GPU"
    notes = [r for r in caplog.records if "measured on" in r.getMessage()
             and r.levelno >= logging.WARNING]
    assert not notes, [r.getMessage() for r in notes]
    assert source.describe().startswith("shipped choice data, measured on another device")
    assert "table(size=8" not in caplog.text
    _, info = blur(np.ones((8, 8, 1), np.float32), albedo=0.8, mfp=1.0, return_info=True)
    assert info.channels[0].auto.data.startswith("shipped choice data"), info
    # the pick is this device's data's (the shipped data with its probe's timings), not the
    # foreign data's (gaussians, measured error 1e-9)
    from bdipole_cl.ops.blur import channel_parameters
    from bdipole_cl.ops.blur.planning import auto_data, plan_channel
    (a, st, eta), = channel_parameters(1, albedo=0.8, mfp=1.0, eta=1.4)
    own = plan_channel("auto", a, st, eta, 1e-3, False, auto_data(on_device))
    assert (info.channels[0].method, info.channels[0].auto) == (own.method, own.auto), info
    assert info.channels[0].auto.measured_error != 1e-9


def test_short_calibration_is_what_auto_then_reads(on_device, cache_dir, caplog):
    """A (short) calibration writes this device's data to the cache; invert_albedo's and
    blur's auto then decide from it and say so. (The first device only: the file's logic is
    the device's no more than the kernels it times, which are checked on every device.)"""
    from conftest import RUNTIMES
    if on_device is not RUNTIMES[0]:
        pytest.skip("calibration's logic checked on the first device")
    path = calibrate(n=4096, blur_size=24, repeats=1, progress=lambda *a: None,
                     sweep=[MethodConfig("table", table_size=64)], sweep_f64=[],
                     blur_sweep=[("direct", 1e-4)], gather_size=48)
    here = DeviceKey.of(on_device.device)
    assert path == calibration_path(here) and path.is_file()
    data, source = choice.choice_for(here)
    assert source.kind == "calibrated" and data.device_key == here
    # the kernels' shapes measured here, and read for this device only
    from bdipole_cl.apps.benchmark import GATHER_WIDTH_CHOICES, TABLE_WIDTH_CHOICES
    from bdipole_cl.ops.blur.dispatch import gather_costs, gather_width
    from bdipole_cl.ops.inversion_kernel import table_width
    tuned = data.kernels
    assert tuned.table_width in TABLE_WIDTH_CHOICES and tuned.gather_width in GATHER_WIDTH_CHOICES
    assert len(tuned.gather_costs) == 3 and all(c >= 0 for c in tuned.gather_costs)
    assert table_width(on_device) == tuned.table_width
    assert gather_width(on_device, 4096) == tuned.gather_width
    assert tuple(vars(gather_costs(on_device)).values()) == tuned.gather_costs
    assert choice.device_tuning(DeviceKey("other", "device", "1")) is None
    assert [c.config.table_size for c in data.inversion] == [64]
    with caplog.at_level(logging.INFO, logger="bdipole_cl"):
        invert_albedo(np.float32([0.5]), 1.4, "auto")
    assert "table(size=64" in caplog.text and "calibrated on this device" in caplog.text
    _, info = blur(np.ones((8, 8, 1), np.float32), albedo=0.8, mfp=0.5, return_info=True)
    pick = info.channels[0]
    assert pick.method == "direct" and pick.auto.truncation_tol == 1e-4, pick
    assert pick.auto.data.startswith("choice data calibrated on this device"), pick


def test_auto_blurs_on_a_gpu_without_its_own_data(cache_dir, monkeypatch):
    """On a device that is not a CPU, the shipped (CPU) data's timings say nothing: auto keeps
    to the methods that run on the device: every one where the FFT runs there (its engine,
    ``widths.fft_engine``: the device on a GPU without timings), never the host FFT."""
    from bdipole_cl.ops.widths import FFT_ENGINE_VARIABLE
    gpu = SimpleNamespace(vendor="Vendor", name="GPU", driver_version="1", type=cl.device_type.GPU)
    rt = Runtime(context=None, queue=SimpleNamespace(device=gpu))
    assert auto_data(rt).methods is None
    monkeypatch.setenv(FFT_ENGINE_VARIABLE, "host")
    auto = auto_data(rt)
    assert auto.methods == ("direct", "gaussians") and "fft" not in auto.methods
    assert auto.source.startswith("shipped choice data, measured on another device")
    from bdipole_cl.ops.blur.planning import plan_channel
    from bdipole_cl.ops.blur.params import channel_parameters
    (a, st, eta), = channel_parameters(1, albedo=0.8, mfp=16.0, eta=1.4)
    assert plan_channel("auto", a, st, eta, 1e-3, False, auto).method != "fft"


@pytest.mark.parametrize("text", [
    "{not json",
    None,                                   # a valid file whose kernels are out of range
])
def test_a_broken_calibration_is_passed_over_and_rewritten(on_device, cache_dir, caplog, text):
    """Every table inversion and texture-varying blur reads the device's calibration: a file
    that is not JSON, or whose kernel widths are not ones the kernels are built for (3, which
    was an OpenCL build error), is passed over with one warning naming it (the per-platform
    defaults then), and `report --calibrate` rewrites it."""
    from bdipole_cl.ops.inversion_kernel import table_width
    here = DeviceKey.of(on_device.device)
    path = calibration_path(here)
    path.parent.mkdir(parents=True)
    if text is None:
        write_choice_data(foreign_data(here), path)
        raw = json.loads(path.read_text())
        raw["kernels"] = {"table_width": 3, "gather_width": "16", "gather_costs": [1, 2]}
        path.write_text(json.dumps(raw))
    else:
        path.write_text(text)
    choice._DATA_CACHE.clear()
    rd = np.linspace(0.05, 0.95, 64, dtype=np.float32)
    with caplog.at_level(logging.WARNING, logger="bdipole_cl"):
        alpha = invert_albedo(rd, 1.4)
        assert table_width(on_device) in (1, 8, 16)
        blur(np.ones((8, 9, 1), np.float32), albedo=np.full((8, 9), 0.6), mfp=1.0)
    notes = [r.getMessage() for r in caplog.records if str(path) in r.getMessage()]
    assert len(notes) == 1 and "passed over" in notes[0] and "--calibrate" in notes[0], notes
    if text is None:
        assert "kernels.table_width: 3" in notes[0], notes
    np.testing.assert_allclose(alpha, invert_albedo(rd, 1.4, method="bisection"), rtol=1e-5)
    calibrate(n=4096, blur_size=24, repeats=1, progress=lambda *a: None,
              sweep=[MethodConfig("table", table_size=64)], sweep_f64=[],
              blur_sweep=[("direct", 1e-4)], gather_size=48)
    assert choice.load_choice_data(path).kernels.table_width in (1, 4, 8, 16)


def test_kernel_shapes_measured_with_other_kernels_are_passed_over(on_device, cache_dir,
                                                                   caplog, monkeypatch):
    """A calibration records the kernel sources its widths and costs were measured with: a
    later version's kernels (another digest) do not run on them (the per-platform defaults
    then, with one note naming the file); the same kernels, or a file without a digest (written
    by hand), do."""
    from bdipole_cl.device.programs import kernels_digest
    from bdipole_cl.ops.blur.dispatch import gather_width
    from bdipole_cl.ops.inversion_kernel import TABLE_WIDTH_VARIABLE, table_width
    from bdipole_cl.ops.blur.dispatch import GATHER_WIDTH_VARIABLE
    monkeypatch.delenv(TABLE_WIDTH_VARIABLE, raising=False)     # (they force a width over all)
    monkeypatch.delenv(GATHER_WIDTH_VARIABLE, raising=False)
    here = DeviceKey.of(on_device.device)
    path = calibration_path(here)
    default = table_width(on_device)
    tuned = 4 if default != 4 else 2
    for digest, used in (("0123456789abcdef", False), (kernels_digest(), True), (None, True)):
        kernels = choice.KernelTuning(tuned, 8, (0.01, 0.0, 0.04), digest)
        write_choice_data(ChoiceData("here", (), (), here, kernels), path)
        assert choice.load_choice_data(path).kernels == kernels       # read back as written
        with caplog.at_level(logging.WARNING, logger="bdipole_cl"):
            caplog.clear()
            got = table_width(on_device), gather_width(on_device, 4096)
        notes = [r.getMessage() for r in caplog.records if "other kernels" in r.getMessage()]
        if used:
            assert got == (tuned, 8) and not notes, (digest, got, notes)
        else:
            assert got[0] == default and len(notes) == 1 and str(path) in notes[0], notes
            assert "--calibrate" in notes[0]
