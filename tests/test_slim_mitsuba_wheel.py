"""tools/dev/slim_mitsuba_wheel.py on a small wheel of Mitsuba's layout: the kept variants' modules, core libraries,
plugins, data and Python files stay byte for byte, the rest goes, config.py lists the kept variants, and RECORD's
hashes match the new files (what pip checks)."""

import base64
import hashlib
import sys
import zipfile

import pytest

from conftest import REPO

sys.path.insert(0, str(REPO / "tools" / "dev"))
import slim_mitsuba_wheel as slim  # noqa: E402

SO = ".cpython-312-x86_64-linux-gnu.so"
VARIANTS = ["scalar_rgb", "scalar_spectral", "llvm_ad_rgb", "cuda_ad_rgb", "cuda_ad_mono_polarized"]


def _wheel(path):
    files = {f"mitsuba/{v}{SO}": v.encode() * 50 for v in VARIANTS}
    files.update(
        {
            "mitsuba/__init__.py": b"from .config import MI_VARIANTS\n",
            "mitsuba/config.py": f"PYTHON_EXECUTABLE = 'x'\nMI_VARIANTS = {VARIANTS!r}\nDRJIT = '1.5.0'\n".encode(),
            f"mitsuba/mitsuba_ext{SO}": b"ext",
            f"mitsuba/mitsuba_alias{SO}": b"alias",
            "mitsuba/libmitsuba.so": b"core" * 100,
            "mitsuba/libembree3.so": b"embree",
            "mitsuba/plugins/diffuse.so": b"plugin",
            "mitsuba/data/srgb.coeff": b"coeff",
            "mitsuba/python/util.py": b"def traverse(): pass\n",
            "mitsuba/__init__.pyi": b"stub",
            "mitsuba/include/mitsuba/core/fwd.h": b"#pragma once",
            "mitsuba/cmake/mitsuba/mitsubaConfig.cmake": b"",
            "mitsuba/pkgconfig/libjpeg.pc": b"",
            "share/doc/mitsuba/README.md": b"doc",
            "mitsuba-3.9.1.dist-info/WHEEL": b"Wheel-Version: 1.0\n",
        }
    )
    with zipfile.ZipFile(path, "w") as z:
        for name, data in files.items():
            z.writestr(name, data)
        z.writestr("mitsuba-3.9.1.dist-info/RECORD", "".join(f"{n},,\n" for n in files))
    return files


def test_slim_keeps_the_chosen_variants_and_rewrites_record(tmp_path):
    src = tmp_path / "in" / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl"
    src.parent.mkdir()
    files = _wheel(src)
    out = slim.slim(src, tmp_path / "out", ["scalar_rgb", "cuda_ad_rgb"])
    assert out.name == src.name and out.parent == tmp_path / "out"
    with zipfile.ZipFile(out) as z:
        names = set(z.namelist())
        kept = {
            f"mitsuba/scalar_rgb{SO}",
            f"mitsuba/cuda_ad_rgb{SO}",
            f"mitsuba/mitsuba_ext{SO}",
            f"mitsuba/mitsuba_alias{SO}",
            "mitsuba/libmitsuba.so",
            "mitsuba/libembree3.so",
            "mitsuba/plugins/diffuse.so",
            "mitsuba/data/srgb.coeff",
            "mitsuba/python/util.py",
            "mitsuba/__init__.py",
            "mitsuba-3.9.1.dist-info/WHEEL",
        }
        assert names == kept | {"mitsuba/config.py", "mitsuba-3.9.1.dist-info/RECORD"}
        for name in kept:
            assert z.read(name) == files[name], name
        assert "MI_VARIANTS = ['scalar_rgb', 'cuda_ad_rgb']" in z.read("mitsuba/config.py").decode()
        record = {
            line.split(",")[0]: line.split(",")[1:]
            for line in z.read("mitsuba-3.9.1.dist-info/RECORD").decode().splitlines()
        }
        assert set(record) == names
        for name in names - {"mitsuba-3.9.1.dist-info/RECORD"}:
            data = z.read(name)
            digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            assert record[name] == [f"sha256={digest}", str(len(data))], name


def test_slim_names_a_missing_variant_and_a_non_mitsuba_wheel(tmp_path):
    src = tmp_path / "mitsuba-3.9.1-cp312-cp312-manylinux_2_28_x86_64.whl"
    _wheel(src)
    with pytest.raises(SystemExit, match="has no variant llvm_ad_spectral"):
        slim.slim(src, tmp_path / "out", ["scalar_rgb", "llvm_ad_spectral"])
    other = tmp_path / "other-1.0-py3-none-any.whl"
    with zipfile.ZipFile(other, "w") as z:
        z.writestr("other/__init__.py", "")
    with pytest.raises(SystemExit, match="not a Mitsuba 3 wheel"):
        slim.slim(other, tmp_path / "out", ["scalar_rgb"])
    with pytest.raises(SystemExit, match="no such wheel"):
        slim.slim(tmp_path / "missing.whl", tmp_path / "out", ["scalar_rgb"])
