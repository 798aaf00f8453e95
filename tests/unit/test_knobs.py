"""Every knob of every method refuses a bad value with a ValueError/TypeError naming it,
before any kernel is built (``make_pipeline``, so ``clrecon.run`` users get the same), and
the device argument and ``LocalSize`` say what is wrong instead of crashing later."""
from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

import clrecon
from clrecon.api import METHODS, make_pipeline
from clrecon.core import device as cldev
from clrecon.core.camera import CocModel
from clrecon.core.knobs import KnobTypeError, check_float, check_int
from clrecon.core.local_size import LocalSize
from clrecon.core.samples import SampleBuffer
from clrecon.methods.box import Box
from clrecon.methods.sweep import max_exponent

BIG = 10**20

#: method -> knob -> bad values (each must raise ValueError or TypeError naming the knob)
BAD = {
    "box": {
        "local": [4, "16x4", (16, 4)],
    },
    "sweep": {
        "scales": [3, 0, True, 2.0, "2"],
        "dof_layers": [1, "yes", None],
        "exponent": [100.0, 0.0, -1.0, math.nan, math.inf, "1.3", True, BIG**20],
        "smooth_motion": [1, "no"],
        "diameter_scale": [-1.0, math.nan, math.inf, 1e7, "1"],
        "sort": ["bubble", 1],
        "tile": [0, -1, 100, 4.0, True, BIG],
        "tile_merge": ["quick", 1],
        "group": [0, -3, 2**31, 2.0, True],
        "specialize": [1, None],
        "exact_depth_order": [1, "yes", None],
    },
    "layered": {
        "mode": ["fast", 1],
        "filter": ["box", 1, ""],
        "tile": [24, 256, 1, 0, 32.0, True],
        "stats_stride": [0, -1, 2**31, 1e12, 24.0, True],
        "merge_threshold": [math.nan, math.inf, -math.inf, 1e7, "0.1"],
        "sigma_x": [0.0, -1.0, 100.0, math.nan, math.inf, "0.33"],
        "max_partitions": [0, 17, 4.0],
        "guard": [1, 1000, 16.0],
        "bucket_coc": [0.0, 1e-9, 1e9, math.nan],
        "splat": ["cubic", 1],
        "seed": [-1, 2**32, 1.5, True],
        "has_motion": [1, "yes"],
        "recursions": [0, 5, 3.0],
        "specialize": [1, None],
        "reach": [0, 5000, 96.0],
        "subsample": [0, 65, 2.5, "lots"],
        "mip_images": [1, "yes"],
        "deterministic": [1, "yes", None],
    },
    "splat": {
        "psf": ["gauss", 1],
        "layers": [0, 65, 100000, 4.0, True],
        "pyramid": ["f9", 7],
        "dense": [1, "yes"],
        "fast_ratio": [-1.0, math.nan, math.inf, 1e9, "1"],
        "max_error": [-0.1, math.nan, -math.inf, "x"],
        "scatter": ["locks", 1],
        "deterministic": [1, "yes", None],
        "mip_radius": [0.5, -1.0, 33.0, math.nan, math.inf, "8", True],
    },
}

CASES = [(m, k, v) for m, knobs in BAD.items() for k, vals in knobs.items() for v in vals]


def _frame(h=6, w=7, s=4):
    rng = np.random.default_rng(5)
    buf = SampleBuffer.zeros(h, w, s, CocModel.from_focus(8.0, 4.0))
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    buf.depth[:] = rng.uniform(2.2, 40.0, buf.depth.shape)
    buf.color[:] = rng.uniform(0, 1, buf.color.shape)
    buf.motion[..., 0] = 2.0
    return buf.validate()


@pytest.fixture(scope="module")
def frame():
    return _frame()


def test_every_knob_is_covered():
    """A knob added to a method's constructor must get bad values here."""
    for name, cls in METHODS.items():
        params = set(inspect.signature(cls.__init__).parameters) - {"self", "context", "info"}
        assert params == set(BAD[name]), f"{name}: knobs without bad values: " \
                                         f"{sorted(params - set(BAD[name]))}"


@pytest.mark.parametrize("method,knob,value", CASES,
                         ids=[f"{m}-{k}={v!r}" for m, k, v in CASES])
def test_bad_knob_names_itself(device, frame, method, knob, value):
    with pytest.raises((ValueError, TypeError)) as info:
        make_pipeline(method, device.context, frame.inspect(), **{knob: value})
    assert knob in str(info.value), str(info.value)
    # a wrong type is a KnobTypeError: a TypeError the command line reports as user input
    if isinstance(info.value, TypeError):
        assert isinstance(info.value, KnobTypeError), type(info.value)


def test_ranges_are_stated(device, frame):
    info = frame.inspect()
    for knobs, text in ((dict(seed=-1), "[0, 4294967296)"),
                        (dict(stats_stride=10**12), "[1, 2147483648)"),
                        (dict(sigma_x=math.inf), "(0, 64]"), (dict(reach=0), "[1, 1024]"),
                        (dict(guard=1), "[2, 256]"), (dict(bucket_coc=0.0), "[0.001, 1000]")):
        with pytest.raises(ValueError, match=text.replace("[", r"\[").replace("(", r"\(")
                           .replace(")", r"\)").replace("]", r"\]")):
            make_pipeline("layered", device.context, info, **knobs)
    with pytest.raises(ValueError, match=r"layers: must be an integer in \[1, 64\]"):
        make_pipeline("splat", device.context, info, layers=100000)
    with pytest.raises(ValueError, match=r"tile: must be an integer in \[1, \d+\].*local memory"):
        make_pipeline("sweep", device.context, info, sort="tile", tile=0)
    for group in (0, 10**6):
        with pytest.raises(ValueError, match=r"group: must be an integer in \[1, \d+\].*"
                                             r"local memory"):
            make_pipeline("sweep", device.context, info, sort="block", group=group)
    e = max_exponent(2, info.spp)
    with pytest.raises(ValueError, match=rf"exponent: .*\(0, {e:g}\] for 2 scales at 4 spp"):
        make_pipeline("sweep", device.context, info, exponent=100.0)


def test_ints_refuse_floats_and_bools():
    """The documented rule: an integer knob takes an int (NumPy too), never a float, even
    8.0, nor a bool; a float knob takes int or float, finite."""
    assert check_int("n", np.int64(8), 1, 10) == 8 and type(check_int("n", 8, 1, 10)) is int
    for bad in (8.0, np.float32(8), True, np.bool_(True), "8"):
        with pytest.raises(KnobTypeError, match="n: must be an integer"):
            check_int("n", bad, 1, 10)
    assert check_float("f", 2) == 2.0 and check_float("f", np.float32(0.5)) == 0.5
    assert check_float("f", math.inf, 0.0, allow_inf=True) == math.inf
    for bad in (math.nan, math.inf, -math.inf, 10**400):
        with pytest.raises(ValueError, match="f: must be a finite number"):
            check_float("f", bad)
    with pytest.raises(KnobTypeError):
        check_float("f", True)
    assert issubclass(KnobTypeError, TypeError) and issubclass(KnobTypeError, ValueError)


@pytest.mark.parametrize("knobs", [dict(seed=2**32 - 1, stats_stride=2**31 - 1),
                                   dict(seed=np.uint32(7), stats_stride=np.int64(5))],
                         ids=["edges", "numpy"])
def test_layered_edge_values_run(device, frame, knobs):
    """The ends of the stated ranges run (seed=2^32 - 1 was an OverflowError at launch)."""
    img = clrecon.reconstruct(frame, "layered", device, specialize=False, **knobs)
    assert np.isfinite(img).all()


def test_splat_layer_bound_runs(device, frame):
    img = clrecon.reconstruct(frame, "splat", device, layers=64)
    assert np.isfinite(img).all()


def test_sweep_exponent_bound_stays_finite(device):
    """The worst case of the exponent bound: every sample in the widest scale (|CoC| 10 px),
    so each weight is about 1 / (25 spp); at the bound the image is finite (100 was NaN)."""
    rng = np.random.default_rng(0)
    spp = 4
    buf = SampleBuffer.zeros(12, 12, spp, CocModel(0.0, 10.0))
    buf.position[:] += rng.uniform(-0.5, 0.499, buf.position.shape)
    buf.color[:] = rng.uniform(0.1, 1, buf.color.shape)
    buf.depth[:] = rng.uniform(1, 10, buf.depth.shape)
    e = max_exponent(2, spp)
    assert 18 < e < 19  # 126 / log2(25 * 4)
    img = clrecon.reconstruct(buf, "sweep", device, sort="pixel", exponent=e)
    assert np.isfinite(img).all()


# -- LocalSize ------------------------------------------------------------------------------

@pytest.mark.parametrize("x,y,err,word", [
    (0, 0, ValueError, "LocalSize.x"), (-1, 4, ValueError, "LocalSize.x"),
    (16, 0, ValueError, "LocalSize.y"), (None, -2, ValueError, "LocalSize.y"),
    (1.5, 4, TypeError, "LocalSize.x"), (8.0, 4, TypeError, "LocalSize.x"),
    (True, 4, TypeError, "LocalSize.x"), (16, None, TypeError, "LocalSize.y"),
    (2**31, 1, ValueError, "LocalSize.x")])
def test_local_size_values(x, y, err, word):
    with pytest.raises(err, match=word):
        LocalSize(x, y)


def test_local_size_normalises_numpy():
    loc = LocalSize(np.int64(8), np.int32(2))
    assert type(loc.x) is int and type(loc.y) is int and loc == LocalSize(8, 2)
    assert LocalSize(None).for_range(5, 3) == ((5, 3), None)


def test_local_size_against_device_limits(device, frame):
    dev = device.device
    items = list(dev.max_work_item_sizes)
    mwg = dev.max_work_group_size
    over_items = LocalSize(items[0] + 1, 1)
    with pytest.raises(ValueError, match=rf"box: local size {items[0] + 1}x1: x = "
                                         rf"{items[0] + 1} exceeds .* {items[0]}"):
        Box(device.context, over_items)
    big = LocalSize(min(items[0], mwg), 2) if items[1] >= 2 else LocalSize(mwg + 1, 1)
    with pytest.raises(ValueError, match=rf"box: local size .* exceeds .*{mwg}"):
        make_pipeline("box", device.context, frame.inspect(), local=big)
    with pytest.raises(ValueError, match="box: local size 4096x4096"):
        clrecon.reconstruct(frame, "box", device, local=LocalSize(4096, 4096))


# -- the device argument --------------------------------------------------------------------

@pytest.mark.parametrize("spec,err", [(1.5, TypeError), (True, TypeError), ([0], TypeError),
                                      (b"0", TypeError), ("", ValueError),
                                      ("   ", ValueError)],
                         ids=["float", "bool", "list", "bytes", "empty", "blank"])
def test_device_argument(spec, err):
    with pytest.raises(err, match="device"):
        cldev.get_device(spec)


def test_device_argument_through_run(frame):
    with pytest.raises(TypeError, match="device: must be a device index"):
        clrecon.run(frame, "box", 1.5)
    assert cldev.get_device(np.int64(0)).info.index == 0
