"""The estimator keywords come from one list, the library's (``request::EstimatorOptions``,
read through the native module): every function and method that takes an ``estimator`` takes
every option of that list with the library's default, and the type stubs say the same."""

import ast
import inspect
import json
import pathlib

import numpy as np
import pytest

import umbra
from umbra import _umbra

OPTIONS = json.loads(_umbra.estimator_options_json())
STUBS = pathlib.Path(umbra.__file__).with_name("__init__.pyi")

# A point query samples once per ray unless asked (the library's 64 is a map's pixel budget).
ONE_SAMPLE = {"transmittance", "transmittance_to_light", "usd_point_transmittance"}
# `points` is the positions there; the jackknife's `--points` is spelled otherwise.
SPELLED = {"transmittance_to_light": {"points": "points_per_estimate"}}


def expected(name):
    want = {}
    for k, default in OPTIONS.items():
        if k == "samples" and name in ONE_SAMPLE:
            default = 1
        want[SPELLED.get(name, {}).get(k, k)] = default
    return want


def estimator_calls():
    """Every public function of the module and method of its classes with an ``estimator``."""
    found = {}
    for name, obj in vars(umbra).items():
        if name.startswith("_"):
            continue
        members = vars(obj).items() if inspect.isclass(obj) else [(name, obj)]
        for mname, f in members:
            if mname.startswith("_") or not inspect.isfunction(f):
                continue
            params = inspect.signature(f).parameters
            if "estimator" in params:
                found[mname if inspect.isclass(obj) else name, obj] = params
    return found


def test_the_list_is_the_librarys():
    # The estimator options, their parameters, then the motion keys of the read options, each
    # set in its declaration order.
    assert list(OPTIONS) == [
        "estimator", "samples", "seed", "granularity", "global_majorant", "colour_walk",
        "step", "kernel", "points",
        "velocity", "shutter", "fps", "velocity_scale", "time_samples",
    ]
    assert OPTIONS["estimator"] == "regular" and OPTIONS["samples"] == 64
    assert umbra._ESTIMATOR_OPTIONS == OPTIONS


def test_every_estimator_call_takes_every_option_with_its_default():
    calls = estimator_calls()
    names = sorted(n for n, _ in calls)
    assert len(calls) >= 8, names
    for (name, _), params in calls.items():
        for k, default in expected(name).items():
            assert k in params, f"{name} lacks {k}"
            assert params[k].default == default, f"{name}: {k}={params[k].default!r}, not {default!r}"


def test_the_stubs_say_the_same():
    tree = ast.parse(STUBS.read_text())
    seen = set()
    for node in ast.walk(tree):
        if not isinstance(node, ast.FunctionDef):
            continue
        args = node.args.args + node.args.kwonlyargs
        names = [a.arg for a in args]
        if "estimator" not in names:
            continue
        seen.add(node.name)
        defaults = dict(zip([a.arg for a in node.args.args][-len(node.args.defaults):],
                            node.args.defaults)) if node.args.defaults else {}
        defaults.update({a.arg: d for a, d in zip(node.args.kwonlyargs, node.args.kw_defaults)
                         if d is not None})
        for k, default in expected(node.name).items():
            assert k in names, f"stub {node.name} lacks {k}"
            assert ast.literal_eval(defaults[k]) == default, f"stub {node.name}: {k}"
    assert seen == {n for n, _ in estimator_calls()}


def test_an_option_the_library_does_not_take_is_named(corpus):
    vol = umbra.Volume(corpus / "gen/cloud_fbm.vdb")
    a, b = np.zeros((1, 3)), np.ones((1, 3))
    with pytest.raises(umbra.InvalidArgument, match="granularity"):
        vol.transmittance(a, b, granularity="voxel")
    with pytest.raises(umbra.InvalidArgument, match="samples"):
        vol.transmittance(a, b, samples=-1)
