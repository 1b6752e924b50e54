"""One bake request, three front ends. The same bake asked for with `umbra bake` flags, a
one-task job file (`umbra batch`) and `umbra.bake(...)` keywords writes the same bytes; every
flag of `umbra bake` is a job key, a Python keyword and a property of the job schema by one
naming rule (the long flag with `-` turned into `_`), with the same default."""

import inspect
import json
import re

import pytest

import umbra

from conftest import DATA

CLOUD = DATA / "cloud.vdb"

# (name, input, flags, output suffix): flags as a TD types them.
CASES = [
    ("flat", CLOUD, ["--light-dir=-1,-1,0.3", "--res", "40x32"], ".exr"),
    (
        "tiled",
        CLOUD,
        ["--light-dir=-1,-1,0.3", "--res", "40x32", "--tile", "16", "--mipmap"],
        ".exr",
    ),
    (
        "deep",
        CLOUD,
        ["--light-pos=0,9,1", "--res", "24x20", "--deep", "--deep-error", "0.01"],
        ".exr",
    ),
    (
        "slices",
        CLOUD,
        ["--light-dir=0.2,-1,0", "--res", "32", "--slices", "3", "--stderr", "--fov", "30",
         "--light-pos=0,9,1"],
        ".exr",
    ),
    (
        "depths-xform",
        CLOUD,
        ["--light-dir=0,-1,0", "--res", "24x24", "--depths", "0.5,2",
         "--xform", "2,0,0,1,0,2,0,0,0,0,2,0,0,0,0,1", "--up=0,0,1", "--interp", "nearest",
         "--density-scale", "0.5"],
        ".exr",
    ),
    ("rgb-scene", None, ["--light-dir=-1,-1,0", "--res", "40x24"], ".exr"),
    (
        "soft-sun",
        CLOUD,
        ["--light-dir=0,-1,0.3", "--res", "20x16", "--light-angle", "6", "--light-samples",
         "64", "--receiver-depth", "3", "--stderr", "--density-scale", "4"],
        ".exr",
    ),
    (
        "soft-sphere-deep",
        CLOUD,
        ["--light-pos=0,6,0", "--res", "12x12", "--light-radius", "1", "--light-samples", "64",
         "--deep"],
        ".exr",
    ),
    (
        "colour-split",
        CLOUD,
        ["--light-dir=0,-1,0", "--res", "20x16", "--sigma-t", "1,0.3,0.1", "--density-scale",
         "4", "--estimator", "track-length", "--samples", "4", "--colour-walk", "split"],
        ".exr",
    ),
    (
        "transmittance-volume",
        CLOUD,
        ["--light-dir=0.3,-1,0.2", "--out-grid", "shadow", "--half"],
        ".vdb",
    ),
    (
        "stochastic",
        CLOUD,
        ["--light-dir=-1,-1,0.3", "--res", "24x20", "--estimator", "ratio", "--samples", "8",
         "--seed", "3", "--stderr", "--granularity", "lower"],
        ".exr",
    ),
    (
        "adaptive",
        CLOUD,
        ["--light-dir=-1,-1,0.3", "--res", "16x16", "--estimator", "jittered", "--step", "0.5",
         "--target-error", "0.02", "--max-spp", "16", "--frame-box=-1,0.5,-1,1,2.5,1"],
        ".exr",
    ),
]


@pytest.fixture(scope="module")
def schema(umbra_bin):
    import subprocess

    out = subprocess.run([str(umbra_bin), "batch", "--schema"], capture_output=True, text=True,
                         check=True).stdout
    return json.loads(out)


def _options(schema):
    return schema["$defs"]["BakeOptions"]["properties"]


def _kinds(prop):
    """The JSON types a schema property takes (following nullable unions)."""
    if "type" in prop:
        t = prop["type"]
        return set(t if isinstance(t, list) else [t])
    kinds = set()
    for alt in prop.get("anyOf", []) + prop.get("oneOf", []):
        kinds |= _kinds(alt)
    return kinds or {"string"}


def _value(key, prop, text):
    """A flag's text as data, by the schema's type of the key."""
    kinds = _kinds(prop) - {"null"}
    if "array" in kinds and "," in text:
        nums = [float(x) for x in text.split(",")]
        # The one nested option: a box is two corners as data, six numbers as a flag.
        return [nums[:3], nums[3:]] if key == "frame_box" else nums
    if "integer" in kinds and "string" not in kinds:
        return int(text)
    if "number" in kinds:
        return float(text)
    return text


def _request(schema, flags):
    """`umbra bake` flags as the request's keys (the naming rule), last flag winning."""
    props = _options(schema)
    out = {}
    i = 0
    while i < len(flags):
        flag = flags[i]
        name, eq, text = flag[2:].partition("=")
        key = name.replace("-", "_")
        assert key in props, f"{flag}: no key {key} in the schema"
        if eq:
            out[key] = _value(key, props[key], text)
        elif _kinds(props[key]) - {"null"} == {"boolean"}:
            out[key] = True
        else:
            i += 1
            out[key] = _value(key, props[key], flags[i])
        i += 1
    return out


def _toml(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    return json.dumps(str(v))


def _scene(tmp_path):
    scene = tmp_path / "scene.toml"
    scene.write_text(
        f'[[volume]]\nfile = "{CLOUD}"\ngrid = "density"\nsigma_t = [1.0, 2.0, 0.5]\n'
    )
    return scene


@pytest.mark.parametrize("name,src,flags,suffix", CASES, ids=[c[0] for c in CASES])
def test_three_front_ends_write_the_same_bytes(cli, schema, tmp_path, name, src, flags, suffix):
    src = src or _scene(tmp_path)
    keys = _request(schema, flags)
    # The command line.
    a = tmp_path / f"cli{suffix}"
    cli("bake", src, *flags, "-o", a, "--quiet")
    # A one-task job file: the same keys in [bake].
    b = tmp_path / "job" / f"job{suffix}"
    job = tmp_path / "job.toml"
    job.write_text(
        f"output = {_toml(str(b))}\n[[inputs]]\nfile = {_toml(str(src))}\n[bake]\n"
        + "".join(f"{k} = {_toml(v)}\n" for k, v in keys.items())
    )
    cli("batch", job, "--quiet")
    # Python keywords: the same keys.
    c = tmp_path / f"py{suffix}"
    umbra.bake(src, c, **keys)
    # A job's output carries its task key (the re-run's skip rule, docs/batch.md) where the
    # CLI's does not; apart from it and the file offsets it moves, the same bytes.
    _same_bytes_but_the_key(a.read_bytes(), b.read_bytes(), name)
    assert a.read_bytes() == c.read_bytes(), f"{name}: Python differs from the CLI"


def _key_entry(data):
    """Where the task key's entry is in a map (an EXR header attribute `umbra:key`: name,
    type, i32 size, value) or a `.vdb` grid's metadata (u32-length name, type and value)."""
    name = b"umbra:key"
    i = data.find(name)
    assert i > 0 and data.find(name, i + 1) < 0, "one key"
    if data[:4] == b"\x76\x2f\x31\x01":
        t = data.index(b"\0", i) + 1
        v = data.index(b"\0", t) + 1
        return i, v + 4 + int.from_bytes(data[v:v + 4], "little", signed=True)
    start = i - 4
    assert int.from_bytes(data[start:i], "little") == len(name)
    k = i + len(name)
    k += 4 + int.from_bytes(data[k:k + 4], "little")  # the type name
    return start, k + 4 + int.from_bytes(data[k:k + 4], "little")


def _same_bytes_but_the_key(a, b, name):
    """`b` is `a` with one key entry more: without it, the same bytes but for the offsets that
    point past it (i64 words larger by its length), a `.vdb` metadata count (one more) and
    the `.vdb` header's content-derived UUID."""
    start, end = _key_entry(b)
    delta = end - start
    rest = b[:start] + b[end:]
    assert len(rest) == len(a), f"{name}: job differs from the CLI beyond its key"
    if a[:4] != b"\x76\x2f\x31\x01":
        # A `.vdb` header's UUID (36 characters at byte 21) is derived from the content.
        assert rest[21:57] != a[21:57], f"{name}: the UUID does not follow the content"
        rest = rest[:21] + a[21:57] + rest[57:]
    i = 0
    while i < len(a):
        if a[i] == rest[i]:
            i += 1
            continue
        moved = False
        for width, step in ((8, delta), (4, 1)):
            # The word holding the first differing byte, lowest start last (little-endian).
            for p in range(i, max(0, i - width + 1) - 1, -1):
                x = int.from_bytes(a[p:p + width], "little", signed=True)
                y = int.from_bytes(rest[p:p + width], "little", signed=True)
                if y - x == step:
                    i, moved = p + width, True
                    break
            if moved:
                break
        assert moved, f"{name}: job differs from the CLI at byte {i} beyond its key"


def _help_flags(cli):
    """Every long flag of `umbra bake --help` with its visible aliases."""
    _, text, _ = cli("bake", "--help")
    flags = re.findall(r"^\s+(?:-\w, )?--([a-z0-9-]+)", text, re.M)
    aliases = re.findall(r"\[aliases: ([^\]]+)\]", text)
    alias_names = [a.strip().lstrip("-") for group in aliases for a in group.split(",")]
    return flags, alias_names


def test_every_flag_is_a_job_key_a_python_keyword_and_a_schema_property(cli, schema):
    flags, aliases = _help_flags(cli)
    props = _options(schema)
    params = inspect.signature(umbra.bake).parameters
    # Not options of the bake: the output (the job's `output`, Python's second argument) and
    # what the command line prints and how it shows progress (Python's `progress` is a callback).
    cli_only = {"output", "quiet", "json", "progress", "help"}
    assert len(flags) > 30
    for flag in flags:
        if flag in cli_only:
            continue
        key = flag.replace("-", "_")
        assert key in props, f"--{flag}: no job key {key}"
        assert key in params, f"--{flag}: no Python keyword {key}"
        assert params[key].kind == inspect.Parameter.KEYWORD_ONLY, key
        # One default everywhere (the CLI's is held to the library's by a Rust test).
        assert params[key].default == props[key].get("default"), key
    for alias in aliases:
        assert alias.replace("-", "_") in params, f"alias --{alias} has no Python keyword"
    # And back: every option of a job's [bake] is a flag, but the job's own framing.
    assert set(props) - {"framing"} == {f.replace("-", "_") for f in flags} - cli_only
    assert "framing" not in params
    # The schema is draft 2020-12 and closed (editors flag a misspelt key).
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["$defs"]["BakeOptions"]["additionalProperties"] is False


def test_each_front_end_names_the_option_its_own_way(cli, tmp_path):
    out = tmp_path / "x.exr"
    code, _, err = cli("bake", CLOUD, "--light-dir=0,-1,0", "--deep-error", "2", "--deep",
                       "-o", out, check=False)
    assert code == 1 and "invalid argument '--deep-error'" in err, err
    job = tmp_path / "job.toml"
    job.write_text(
        f'output = "{out}"\n[[inputs]]\nfile = "{CLOUD}"\n[bake]\nlight_dir = [0, -1, 0]\n'
        "deep = true\ndeep_error = 2.0\n"
    )
    code, _, err = cli("batch", job, check=False)
    assert code == 1 and "bake.deep_error" in err, err
    with pytest.raises(umbra.InvalidArgument, match="'deep_error'"):
        umbra.bake(CLOUD, out, light_dir=(0, -1, 0), deep=True, deep_error=2.0)
    # A keyword of the wrong type is named too.
    with pytest.raises(umbra.InvalidArgument, match="'tile'"):
        umbra.bake(CLOUD, out, light_dir=(0, -1, 0), tile="big")
    # A map-only option on a transmittance volume, in every front end.
    vdb = tmp_path / "t.vdb"
    code, _, err = cli("bake", CLOUD, "--light-dir=0,-1,0", "--tile", "16", "-o", vdb,
                       check=False)
    assert code == 1 and "'--tile': applies to maps" in err, err
    with pytest.raises(umbra.InvalidArgument, match="'tile': applies to maps"):
        umbra.bake(CLOUD, vdb, light_dir=(0, -1, 0), tile=16)
    assert not out.exists() and not vdb.exists()


def test_old_spellings_are_aliases(tmp_path):
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    kw = dict(light_dir=(-1, -1, 0), res=16, estimator="ratio", seed=2)
    umbra.bake(CLOUD, a, samples=4, **kw)
    umbra.bake(CLOUD, b, spp=4, **kw)
    assert a.read_bytes() == b.read_bytes()
    umbra.bake(CLOUD, b, spp=4, overwrite=True, **kw)
    with pytest.raises(umbra.FileError, match="force=True"):
        umbra.bake(CLOUD, b, samples=4, **kw)
    with pytest.raises(umbra.InvalidArgument, match="'spp'"):
        umbra.bake(CLOUD, b, samples=8, spp=4, force=True, **kw)



def test_the_colour_walk_keyword_traces_as_the_command_line(cli, tmp_path):
    v = umbra.Volume.from_scene(_scene(tmp_path), density_scale=4.0)
    o, e = [[-2.0, 0.0, 0.0]], [[2.0, 0.5, 0.0]]
    got = {}
    for walk in ("shared", "split"):
        t = v.transmittance(o, e, "track-length", 128, colour_walk=walk)
        _, out, _ = cli("query", _scene(tmp_path), "--density-scale", "4", "--from", "-2,0,0",
                        "--to", "2,0.5,0", "--estimator", "track-length", "--spp", "128",
                        "--colour-walk", walk, "--json")
        assert list(t[0]) == json.loads(out)["T"], walk
        got[walk] = t
    assert (got["shared"] != got["split"]).any()
    with pytest.raises(umbra.InvalidArgument, match="colour_walk"):
        v.transmittance(o, e, "ratio", 4, colour_walk="both")
