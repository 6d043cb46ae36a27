"""Rewrite a Mitsuba 3 wheel keeping only some variants (default: scalar_rgb and cuda_ad_rgb), so that it fits what
can be carried to the offline GPU machine (64 MiB a call; the full cp312 wheel is ~62.5 MB, drjit's another ~5 MB).

    python tools/dev/slim_mitsuba_wheel.py WHEEL OUT_DIR [--variants scalar_rgb,cuda_ad_rgb]

Kept: the core libraries (libmitsuba, libembree3, OpenEXR, ...), the plugins (each plugin is one library holding
every variant), data/, the Python package files and the kept variants' extension modules. Dropped: the other
variants' extension modules, C++ headers (include/), CMake and pkg-config files, share/doc and the .pyi type stubs.
config.py's MI_VARIANTS lists the kept variants only and the wheel's RECORD is rewritten with the new files' hashes.
mitsuba.variants() still lists every variant of the build (the list is compiled in); set_variant of a dropped one raises
ModuleNotFoundError. The output has the input's file name, in OUT_DIR.

Check (the wheel's Python): pip install --no-deps --target DIR OUT_DIR/mitsuba-*.whl drjit-*.whl, then
PYTHONPATH=DIR python -c "import mitsuba; mitsuba.set_variant('scalar_rgb')"."""

from __future__ import annotations

import argparse
import base64
import hashlib
import re
import sys
import zipfile
from pathlib import Path

DROP_DIRS = ("mitsuba/include/", "mitsuba/cmake/", "mitsuba/pkgconfig/", "share/")
VARIANT_MODULE = re.compile(r"^mitsuba/(?P<variant>(scalar|llvm|cuda)_[a-z_]+)\.cpython-[^/]+\.so$")


def keep(name: str, variants: set[str]) -> bool:
    """Whether a wheel member is kept."""
    if name.startswith(DROP_DIRS) or (name.endswith(".pyi") and name.startswith("mitsuba/")):
        return False
    m = VARIANT_MODULE.match(name)
    return m is None or m.group("variant") in variants


def _record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def slim(wheel: Path, out_dir: Path, variants: list[str]) -> Path:
    if not wheel.is_file():
        raise SystemExit(f"slim_mitsuba_wheel: no such wheel: {wheel}")
    out_dir.mkdir(parents=True, exist_ok=True)
    out = out_dir / wheel.name
    if out.resolve() == wheel.resolve():
        raise SystemExit("slim_mitsuba_wheel: OUT_DIR must not be the input wheel's folder")
    with zipfile.ZipFile(wheel) as src:
        names = src.namelist()
        config = "mitsuba/config.py"
        if config not in names:
            raise SystemExit(f"slim_mitsuba_wheel: {wheel.name} has no {config}: not a Mitsuba 3 wheel")
        present = {m.group("variant") for m in map(VARIANT_MODULE.match, names) if m}
        missing = [v for v in variants if v not in present]
        if missing:
            raise SystemExit(
                f"slim_mitsuba_wheel: {wheel.name} has no variant {', '.join(missing)} "
                f"(it has: {', '.join(sorted(present))})"
            )
        record = next(n for n in names if n.endswith(".dist-info/RECORD"))
        lines = []
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as dst:
            for info in src.infolist():
                name = info.filename
                if name == record or not keep(name, set(variants)):
                    continue
                data = src.read(info)
                if name == config:
                    text, n = re.subn(r"^MI_VARIANTS = .*$", f"MI_VARIANTS = {variants!r}", data.decode(), flags=re.M)
                    if n != 1:
                        raise SystemExit(f"slim_mitsuba_wheel: no MI_VARIANTS line in {config}")
                    data = text.encode()
                new = zipfile.ZipInfo(name, info.date_time)
                new.external_attr, new.compress_type = info.external_attr, zipfile.ZIP_DEFLATED
                dst.writestr(new, data, compresslevel=9)
                if not name.endswith("/"):
                    lines.append(_record_line(name, data))
            lines.append(f"{record},,")
            info = zipfile.ZipInfo(record, src.getinfo(record).date_time)
            info.external_attr = src.getinfo(record).external_attr
            dst.writestr(info, "\n".join(lines) + "\n", zipfile.ZIP_DEFLATED)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("wheel", type=Path)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument(
        "--variants",
        default="scalar_rgb,cuda_ad_rgb",
        help="comma-separated variants to keep (default: scalar_rgb,cuda_ad_rgb)",
    )
    args = ap.parse_args(argv)
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    if not variants:
        raise SystemExit("slim_mitsuba_wheel: --variants names no variant")
    out = slim(args.wheel, args.out_dir, variants)
    print(
        f"{out}: {out.stat().st_size / 1e6:.1f} MB (was {args.wheel.stat().st_size / 1e6:.1f} MB), "
        f"variants {', '.join(variants)}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
