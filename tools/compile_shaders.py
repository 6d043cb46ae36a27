#!/usr/bin/env python3
"""Regenerate shaders/glsl/include/interface.glsl (engine/passes/interface.py), compile
shaders/glsl/*.{vert,frag,comp} into shaders/spv/ and rewrite the manifest of source hashes.

    python tools/compile_shaders.py           # rebuild every shader + manifest
    python tools/compile_shaders.py --check   # exit 1 and list the shaders whose SPIR-V is stale
"""

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from engine.errors import ShaderError  # noqa: E402
from engine.passes.interface import glsl_text, write_glsl  # noqa: E402
from engine.shaders import GLSL_DIR, SPV_DIR, compile_all, stale_shaders  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="only report stale SPIR-V; exit 1 if any")
    args = ap.parse_args()
    if args.check:
        stale = stale_shaders(GLSL_DIR, SPV_DIR)
        if (GLSL_DIR / "include" / "interface.glsl").read_text() != glsl_text():
            stale.insert(0, "include/interface.glsl (generated)")
        if stale:
            print("stale SPIR-V (run tools/compile_shaders.py): " + ", ".join(stale))
            return 1
        print("SPIR-V up to date")
        return 0
    if write_glsl():
        print("rewrote shaders/glsl/include/interface.glsl")
    try:
        manifest = compile_all(GLSL_DIR, SPV_DIR)
    except ShaderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for old in SPV_DIR.glob("*.spv"):
        if old.name[:-4] not in manifest:
            old.unlink()
    print(f"compiled {len(manifest)} shaders into {SPV_DIR}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
