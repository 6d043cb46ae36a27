"""Property-based fuzzing (hypothesis) of the TOML scene loader and the Tracer's input checks, and the hostile
corpus (tests/data/hostile/): every input either loads or raises a ConfigError / SceneError with a one-line
message, never another exception.

The default profile is derandomized and small (the same examples every run, a few seconds); explore further with
`pytest tests/test_fuzz.py --hypothesis-profile=deep` (randomized, 20x the examples).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image

from engine.errors import ConfigError, EngineError, SceneError
from engine.limits import MAX_COORD
from engine.rt.checks import check_batch_size, check_mesh, check_rays
from engine.scene import Scene
from engine.scene.scene import scene_from_dict
from engine.scene.toml_format import CAMERA_KEYS, LIGHT_KEYS, MESH_COMMON, PRIMITIVE_PARAMS

HOSTILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "hostile")
# hypothesis's own casts of out-of-range values while it builds arrays
pytestmark = pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")

_COMMON = dict(
    deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
)
settings.register_profile("default", max_examples=120, derandomize=True, **_COMMON)
settings.register_profile("deep", max_examples=2400, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


def assert_clean_error(exc: BaseException) -> None:
    """An error a user is meant to see: ours, one line, nothing that moves the terminal's cursor."""
    assert isinstance(exc, (ConfigError, SceneError)), f"{type(exc).__name__}: {exc}"
    msg = str(exc)
    assert msg and msg.isprintable(), repr(msg)  # no newline, escape sequence or other control character
    assert len(msg) <= 2000, len(msg)


# ------------------------------------------------------------------------------------------------ TOML values
HOSTILE_TEXT = st.one_of(
    st.text(max_size=12),
    st.sampled_from(
        [
            "",
            ".",
            "..",
            "/",
            "/etc/passwd",
            "../tri.obj",
            "a\nb",
            "\x1b[2J\x1b[31m",
            "\u202eabc",
            "x\x00y",
            "tri.obj",
            "red.png",
            "sub/../tri.obj",
            "./tri.obj",
            "missing.glb",
            "s.toml",
            "x" * 600,
            "#ffffff",
            "#12345",
            "#gggggg",
            "box",
            "sphere",
            "point",
            "spot",
        ]
    ),
)
NUMBERS = st.one_of(
    st.integers(-4, 12),
    st.floats(-10, 10),
    st.integers(),
    st.floats(),  # floats(): NaN, +-inf, huge, tiny
    st.sampled_from([0, -0.0, 5e-324, 1e-300, 1e11, 1e18, 1e30, 1.1e30, 1e300, 2**63, -(2**63), 2**64, 4097, 10**40]),
)
SCALARS = st.one_of(NUMBERS, st.booleans(), HOSTILE_TEXT, st.datetimes(), st.dates(), st.times())
VALUES = st.recursive(
    SCALARS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(HOSTILE_TEXT, inner, max_size=3), max_leaves=6
)
VECTORS = st.one_of(
    st.lists(NUMBERS, min_size=3, max_size=3),
    st.lists(NUMBERS, min_size=0, max_size=5),
    st.lists(st.floats(-5, 5), min_size=3, max_size=3),
)
COUNTS = st.one_of(st.integers(-2, 24), st.sampled_from([0, 2, 4097, 10**20, -1, 2.5, True]))


def _field(key):
    """Plausible values for a key (so that loads get far), mixed with anything at all."""
    plausible = {
        "primitive": st.sampled_from(list(PRIMITIVE_PARAMS)),
        "file": st.sampled_from(
            [
                "tri.obj",
                "quad.ply",
                "missing.obj",
                "../tri.obj",
                "red.png",
                "s.toml",
                ".",
                "/etc/hostname",
                "sub/../tri.obj",
                "link_out.obj",
            ]
        ),
        "texture": st.sampled_from(["red.png", "missing.png", "../red.png", "tri.obj", ".", "bomb_169mpx.png"]),
        "name": HOSTILE_TEXT,
        "color": st.one_of(VECTORS, st.sampled_from(["#ff8000", "#ff800080", "#FFF", "red"])),
        "rotate": st.one_of(VECTORS, st.fixed_dictionaries({"axis": VECTORS, "angle": NUMBERS})),
        "segments": COUNTS,
        "rings": COUNTS,
        "sides": COUNTS,
        "type": st.sampled_from(list(LIGHT_KEYS)),
    }.get(key)
    if plausible is None:
        plausible = st.one_of(NUMBERS, VECTORS)
    return st.one_of(plausible, plausible, plausible, VALUES)


def _table(keys):
    return st.fixed_dictionaries({}, optional={k: _field(k) for k in keys})


MESH_KEYS = sorted(set(MESH_COMMON) | {k for params in PRIMITIVE_PARAMS.values() for k in params})
LIGHT_ALL = sorted({k for keys in LIGHT_KEYS.values() for k in keys})
MESH = st.one_of(
    st.fixed_dictionaries(
        {"primitive": _field("primitive")}, optional={k: _field(k) for k in MESH_KEYS if k != "primitive"}
    ),
    st.fixed_dictionaries({"file": _field("file")}, optional={k: _field(k) for k in MESH_COMMON if k != "file"}),
    _table(MESH_KEYS),
    VALUES,
)
LIGHT = st.one_of(
    st.fixed_dictionaries({"type": _field("type")}, optional={k: _field(k) for k in LIGHT_ALL if k != "type"}), VALUES
)
SCENE = st.fixed_dictionaries(
    {"mesh": st.one_of(st.lists(MESH, min_size=1, max_size=3), VALUES)},
    optional={
        "light": st.one_of(st.lists(LIGHT, max_size=3), VALUES),
        "camera": st.one_of(_table(CAMERA_KEYS), VALUES),
        "settings": st.one_of(st.dictionaries(HOSTILE_TEXT, VALUES, max_size=3), VALUES),
        "\x1b[2Jextra": VALUES,
    },
)


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    """A scene folder with a triangle OBJ, a quad PLY, a PNG, the 169 Mpixel PNG, a symlink leading outside."""
    import trimesh

    root = tmp_path_factory.mktemp("fuzz")
    folder = root / "scene"
    (folder / "sub").mkdir(parents=True)
    with open(folder / "tri.obj", "w") as fh:
        fh.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]]).export(folder / "quad.ply")
    Image.new("RGB", (4, 4), (10, 200, 30)).save(folder / "red.png")
    os.symlink(os.path.join(HOSTILE, "bomb_169mpx.png"), folder / "bomb_169mpx.png")  # (HOSTILE is outside)
    with open(root / "outside.obj", "w") as fh:
        fh.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    os.symlink(root / "outside.obj", folder / "link_out.obj")
    return folder


@given(data=SCENE)
def test_fuzzed_toml_tables_load_or_fail_cleanly(scene_dir, data):
    try:
        scene = scene_from_dict(data, str(scene_dir / "s.toml"))
    except EngineError as exc:
        assert_clean_error(exc)
        return
    except Exception as exc:  # anything else is a bug
        raise AssertionError(f"{type(exc).__name__}: {exc}") from exc
    assert scene.triangle_count >= 1 and np.all(np.isfinite(scene.positions))
    assert np.abs(scene.positions).max() <= MAX_COORD


VALID_TOML = (
    b'[camera]\neye = [0.0, 2.0, 5.0]\ntarget = [0, 0, 0]\nfov = 45\n\n[[mesh]]\nname = "ball"\n'
    b'primitive = "sphere"\nsegments = 8\nrings = 4\ncolor = "#d8c8a8"\n\n[[mesh]]\nfile = "tri.obj"\n'
    b'texture = "red.png"\nscale = [1, 2, 1]\nrotate = {axis = [0, 1, 0], angle = 30}\n\n[[light]]\n'
    b'type = "spot"\nposition = [0, 4, 0]\ntarget = [0, 0, 0]\ncone_angle = 25\n\n[settings]\n'
    b'shadows = "soft"\n'
)
EDITS = st.lists(
    st.tuples(
        st.integers(0, len(VALID_TOML)),
        st.integers(0, 3),
        st.sampled_from(
            [
                b"",
                b"\xef\xbb\xbf",
                b"\x00",
                b"\xff",
                b"[",
                b"]",
                b"{",
                b"=",
                b'"',
                b"\n",
                b"\\",
                b"'''",
                b"[[mesh]]",
                b"nan",
                b"-inf",
                b"1e999",
                b"../",
                b"/etc/passwd",
                b"\x1b[2J",
                b"\r",
                b"#",
                b"\xc3",
                b"0x7fff",
            ]
        ),
    ),
    min_size=1,
    max_size=4,
)


@given(edits=EDITS)
def test_fuzzed_toml_text_loads_or_fails_cleanly(scene_dir, edits):
    text = VALID_TOML
    for at, cut, insert in edits:  # delete `cut` bytes at `at`, insert `insert` there
        at = min(at, len(text))
        text = text[:at] + insert + text[at + cut :]
    path = scene_dir / "fuzzed.toml"
    path.write_bytes(text)
    try:
        Scene.load(path)
    except EngineError as exc:
        assert_clean_error(exc)
    except Exception as exc:
        raise AssertionError(f"{type(exc).__name__}: {exc} (text {text!r})") from exc


def test_the_unedited_text_loads(scene_dir):
    path = scene_dir / "valid.toml"
    path.write_bytes(VALID_TOML)
    scene = Scene.load(path)
    assert [s.name for s in scene.submeshes] == ["ball", "tri.obj"] and scene.lights[0].kind == "spot"


# ------------------------------------------------------------------------------------------------ Tracer checks
DTYPES = st.one_of(
    hnp.floating_dtypes(),
    hnp.integer_dtypes(),
    hnp.unsigned_integer_dtypes(),
    hnp.boolean_dtypes(),
    hnp.complex_number_dtypes(),
    hnp.datetime64_dtypes(),
    hnp.byte_string_dtypes(max_len=4),
    hnp.unicode_string_dtypes(max_len=4),
)
HUGE = st.sampled_from(
    [
        0.0,
        -0.0,
        1e-45,
        1e-38,
        1e-30,
        1.0,
        -1.0,
        1e10,
        1e11,
        1.0000001e11,
        3.4e38,
        3.5e38,
        1e300,
        np.inf,
        -np.inf,
        np.nan,
    ]
)


@st.composite
def ray_arrays(draw, n):
    """(n, 3) mostly: float32/64 with hostile values, or another dtype, or another shape, or not an array."""
    kind = draw(st.integers(0, 9))
    if kind <= 5:
        dtype = draw(st.sampled_from([np.float32, np.float64]))
        elements = st.one_of(st.floats(-100, 100, width=32), HUGE)
        return draw(hnp.arrays(dtype, (n, 3), elements=elements))
    if kind == 6:
        return draw(hnp.arrays(DTYPES, draw(st.sampled_from([(n, 3), (n,), (n, 4), (3,), (), (n, 3, 1)]))))
    if kind == 7:
        return draw(hnp.arrays(DTYPES, hnp.array_shapes(min_dims=0, max_dims=3, max_side=4)))
    if kind == 8:
        return draw(
            st.lists(
                st.lists(st.one_of(st.floats(), st.integers(), st.none(), st.text(max_size=2)), min_size=2, max_size=4),
                min_size=0,
                max_size=4,
            )
        )  # ragged or mixed lists
    return draw(
        st.one_of(
            st.none(),
            st.text(max_size=5),
            st.integers(),
            st.floats(),
            st.dictionaries(st.text(max_size=2), st.integers(), max_size=2),
            st.just(np.zeros((n, 3), dtype=object)),
            st.just([[1, 2, 3]] * n),
        )
    )


@given(data=st.data())
def test_fuzzed_rays_pass_or_fail_cleanly(data):
    n = data.draw(st.integers(0, 6))
    origins, directions = data.draw(ray_arrays(n)), data.draw(ray_arrays(n))
    tmax = data.draw(
        st.one_of(
            HUGE,
            st.floats(),
            st.integers(),
            st.none(),
            st.text(max_size=3),
            hnp.arrays(
                st.sampled_from([np.float32, np.float64, np.int32, np.bool_, object]),
                st.sampled_from([(n,), (n, 1), (n + 1,), ()]),
            ),
        )
    )
    try:
        o, d, t = check_rays(origins, directions, tmax)
    except EngineError as exc:
        assert_clean_error(exc)
        return
    except Exception as exc:
        raise AssertionError(f"{type(exc).__name__}: {exc}") from exc
    m = len(o)
    assert o.dtype == d.dtype == t.dtype == np.float32 and o.shape == d.shape == (m, 3) and t.shape == (m,)
    assert np.all(np.abs(o) <= MAX_COORD) and np.all(np.isfinite(d)) and not np.any(np.isnan(t))
    assert np.all(np.abs(d).max(axis=1, initial=0) >= np.finfo(np.float32).tiny)


@given(data=st.data())
def test_fuzzed_meshes_pass_or_fail_cleanly(data):
    v = data.draw(ray_arrays(data.draw(st.integers(0, 5))))
    faces = data.draw(
        st.one_of(
            hnp.arrays(
                st.sampled_from([np.int32, np.int64, np.float64]),
                st.sampled_from([(1, 3), (2, 3), (0, 3), (3,), (2, 4)]),
                elements=st.one_of(st.integers(-3, 6), st.sampled_from([2**31 - 1, 255])),
            ),
            hnp.arrays(st.sampled_from([np.uint64, np.uint8, np.bool_]), st.sampled_from([(1, 3), (2, 3)])),
            st.lists(st.lists(st.integers(-2, 5), min_size=3, max_size=3), max_size=3),
            st.none(),
            st.text(max_size=3),
        )
    )
    try:
        vertices, f = check_mesh(v, faces)
    except EngineError as exc:
        assert_clean_error(exc)
        return
    except Exception as exc:
        raise AssertionError(f"{type(exc).__name__}: {exc}") from exc
    assert vertices.dtype == np.float32 and vertices.ndim == 2 and vertices.shape[1] == 3
    assert np.all(np.abs(vertices) <= MAX_COORD)
    assert f.dtype == np.int64 and len(f) >= 1 and f.min() >= 0 and f.max() < len(vertices)


@given(
    value=st.one_of(
        st.integers(),
        st.floats(),
        st.booleans(),
        st.none(),
        st.text(max_size=3),
        st.sampled_from([np.int64(5), np.float32(2.0), np.float64(np.nan), 10**400, 1e6, 2.5]),
        hnp.arrays(np.int64, (2,)),
    )
)
def test_fuzzed_batch_sizes_pass_or_fail_cleanly(value):
    try:
        n = check_batch_size(value)
    except EngineError as exc:
        assert_clean_error(exc)
        return
    except Exception as exc:
        raise AssertionError(f"{type(exc).__name__}: {exc}") from exc
    assert isinstance(n, int) and n >= 1 and n == value


# ------------------------------------------------------------------------------------------------ hostile corpus
# Every file of tests/data/hostile: what loading it does (None: it loads; a list: parts of its one-line error).
# Files the others refer to (the PNG bombs, an MTL) are listed in REFERENCED.
CORPUS = {
    "abs_path.toml": ["[[mesh]] #1: file = '/etc/passwd' is outside the scene's folder"],
    "ansi_file.toml": ["file = '\\x1b]0;title\\x07.obj': file not found"],
    "ansi_name.toml": ["mesh '\\x1b[2J\\x1b[31mred\\nline'"],
    "bad_accessor.gltf": ["POSITION refers to accessor 7, but the file has 1 accessor"],
    "bad_escape.toml": ["TOML syntax error", "line 3"],
    "bidi_name.toml": ["mesh 'abc\\u202edcba\\u2028x'"],
    "bom.toml": None,
    "bom_utf16.toml": ["not a UTF-8 text file"],
    "bomb_texture.obj": None,  # the texture is left out, with a warning
    "deep_array.toml": ["nested too deeply"],
    "deep_inline.toml": ["nested too deeply"],
    "dotdot_missing.toml": ["file = '../no-such-folder/model.obj' is outside the scene's folder"],
    "dotdot_sneaky.toml": ["is outside the scene's folder"],
    "dotdot_texture.toml": ["texture = '../../../../../../../../etc/hostname' is outside the scene's folder"],
    "dup_key.toml": ["TOML syntax error", "Cannot overwrite a value"],
    "empty.stl": ["empty.stl: file is empty"],
    "empty.toml": ["no [[mesh]] tables"],
    "escape_node.gltf": ["mesh 'node\\x1b[2J\\nX' has 1 vertex position(s) that are NaN or infinite"],
    "garbage.ply": ["cannot read .ply file"],
    "huge_coords.obj": ["world-space vertex coordinates beyond +-1e+11"],
    "huge_int.toml": ["segments must be an integer in [3, 4096], got 9223372036854775807"],
    "index_past_end.obj": ["cannot read .obj file"],
    "json_array.gltf": ["its JSON is a list, not an object"],
    "light_list_type.toml": ["[[light]] #1: type must be one of"],
    "long_name.toml": ["mesh 'xxxxx", "x...x", "has world-space"],
    "long_value.toml": ["color must be 3 numbers", "f...f"],
    "mesh_is_toml.toml": ["a .toml scene cannot be used as a mesh file"],
    "mesh_not_table.toml": ["[[mesh]] #1: must be a table"],
    "nan_inf.toml": ["translate must be finite"],
    "nan_vertex.obj": ["1 vertex position(s) that are NaN or infinite"],
    "newline_texture.toml": ["texture = 'a\\nb.png': file not found"],
    "no_buffers.gltf": ["bufferViews[0] refers to buffer 0, but the file has no buffers"],
    "not_json.gltf": ["a .gltf is JSON text", "not valid JSON"],
    "nul_path.toml": ["a path may not contain a NUL character"],
    "settings_odd.toml": None,  # [settings] are the renderer's to check
    "texture_bomb.toml": ["texture image is too large: 169,000,000 pixels (13000 x 13000)"],
    "texture_bomb196.toml": ["texture image is too large: 196,000,000 pixels"],
    "texture_dir.toml": ["texture = '.': not a regular file"],
    "truncated.glb": ["the JSON chunk of this .glb is not valid JSON"],
    "zero_index.obj": ["line 6: face index 0"],
    "zero_uv_index.obj": ["line 7: face index 0"],
}
REFERENCED = {"bomb_169mpx.png", "bomb_196mpx.png", "bomb_texture.mtl", "README.md"}


def test_the_corpus_is_all_listed():
    assert set(os.listdir(HOSTILE)) == set(CORPUS) | REFERENCED


@pytest.mark.parametrize("name", sorted(CORPUS))
def test_hostile_corpus(name):
    expected = CORPUS[name]
    try:
        scene = Scene.load(os.path.join(HOSTILE, name))
    except EngineError as exc:
        assert_clean_error(exc)
        assert expected is not None, f"{name} should load: {exc}"
        msg = str(exc)
        assert msg.startswith(os.path.join(HOSTILE, name) + ": "), msg
        for part in expected:
            assert part in msg, f"{part!r} not in {msg!r}"
        return
    assert expected is None, f"{name} loaded, expected an error with {expected}"
    assert scene.triangle_count >= 1
