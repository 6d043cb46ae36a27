"""Build the API reference from the docstrings with pdoc (HTML, into docs/api/ by default) and check it.

    .venv/bin/python tools/build_api_docs.py               # writes docs/api/index.html, engine.html, ...
    ./hybrid docs                                           # the same (setting up the checkout's .venv first)
    .venv/bin/python tools/build_api_docs.py -o /tmp/api    # elsewhere
    .venv/bin/python tools/build_api_docs.py --check        # check only, write nothing

Warnings are errors: every warning pdoc gives (an annotation it cannot evaluate, a module it cannot import, ...),
every backticked reference in a docstring that does not resolve (`engine.settings.DEFAULT_SETTINGS`,
`Frame.aov`, `Scene.load()`: names under `engine.` or starting with a public class) and every `docs/*.md` a
docstring names that does not exist is printed, and the exit status is 1. tests/test_api_docs.py runs it.

The folder is a site to open in a browser: index.html lists the modules and the public API (`engine.__all__`) with
the first sentence of each docstring, linked to pdoc's pages (engine.html, engine/settings.html, ...).
"""

from __future__ import annotations

import argparse
import dataclasses
import html
import importlib
import re
import sys
import tempfile
import types
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

#: The documented modules: the public API (engine/__init__.py's __all__), the render options, the coordinate bound,
#: frame files (read_exr, ...) and camera sequences (orbit_cameras, ...).
MODULES = ["engine", "engine.settings", "engine.limits", "engine.outputs", "engine.sequence"]
DOCFORMAT = "google"
CODE_SPAN = re.compile(r"`([A-Za-z_][\w.]*)(?:\(\))?`")
DOC_PATH = re.compile(r"\bdocs/[\w./-]+\.md\b")


def _has(obj, name: str) -> bool:
    """An attribute, a slot, an annotated (instance) attribute or a dataclass field of `obj` or its bases."""
    if hasattr(obj, name):
        return True
    for cls in getattr(obj, "__mro__", ()):
        if name in getattr(cls, "__annotations__", {}) or name in getattr(cls, "__slots__", ()):
            return True
    return dataclasses.is_dataclass(obj) and name in {f.name for f in dataclasses.fields(obj)}


def _resolve(dotted: str, public: dict) -> bool:
    """Whether a dotted reference names something: a module path under `engine`, then attributes."""
    parts = dotted.split(".")
    if parts[0] == "engine":
        obj, i = importlib.import_module("engine"), 1
        while i < len(parts):
            try:
                obj = importlib.import_module(".".join(parts[: i + 1]))
            except ImportError:
                break
            i += 1
    else:
        obj, i = public[parts[0]], 1
    for name in parts[i:]:
        if not _has(obj, name):
            return False
        obj = getattr(obj, name, None)
    return True


def check_docstrings(docs) -> list[str]:
    """Problems with the references in the docstrings of the documented objects (pdoc.doc objects)."""
    import engine

    public = {name: getattr(engine, name) for name in engine.__all__}
    problems, seen = [], set()

    def walk(doc):
        if doc.fullname in seen:
            return
        seen.add(doc.fullname)
        text = doc.docstring or ""
        for ref in CODE_SPAN.findall(text):
            head = ref.split(".")[0]
            if (head == "engine" or head in public) and not _resolve(ref, public):
                problems.append(f"{doc.fullname}: `{ref}` does not resolve")
        for path in DOC_PATH.findall(text):
            if not (REPO / path).is_file():
                problems.append(f"{doc.fullname}: {path} does not exist")
        for member in getattr(doc, "members", {}).values():
            walk(member)

    for doc in docs:
        walk(doc)
    return problems


class _Alias:
    """A stand-in for a numpy.typing alias in the pages: pdoc would print `ArrayLike` as the 12-member Union it
    stands for, and `NDArray[np.float32]` as `numpy.ndarray[tuple[typing.Any, ...], numpy.dtype[...]]`."""

    @staticmethod
    def make(name: str) -> type:
        return type(
            name,
            (),
            {
                "__module__": "numpy.typing",
                "__class_getitem__": classmethod(lambda cls, args: types.GenericAlias(cls, args)),
            },
        )


def _short_numpy_aliases(pdoc_doc, pdoc_doc_types) -> None:
    """Evaluate string annotations (the modules use `from __future__ import annotations`) with `ArrayLike` and
    `NDArray` as named stand-ins, so that the reference shows `numpy.typing.ArrayLike` and
    `numpy.typing.NDArray[numpy.float32]`. Display only: help(), IDEs and type checkers see the real aliases."""
    stand_ins = {name: _Alias.make(name) for name in ("ArrayLike", "NDArray")}
    original = pdoc_doc_types.safe_eval_type

    def safe_eval_type(t, globalns, localns, module, fullname):
        if isinstance(t, str) and any(name in t for name in stand_ins):
            globalns = {**globalns, **{k: v for k, v in stand_ins.items() if globalns.get(k) is not None}}
        return original(t, globalns, localns, module, fullname)

    pdoc_doc.safe_eval_type = pdoc_doc_types.safe_eval_type = safe_eval_type


def _summary(docstring: str | None) -> str:
    """The first sentence of a docstring's first paragraph, as plain text (backticks dropped), HTML-escaped."""
    para = " ".join((docstring or "").strip().split("\n\n")[0].split()).replace("`", "")
    m = re.match(r"(.+?\.)(\s|$)", para)
    text = m.group(1) if m else para
    return html.escape(text if len(text) <= 160 else text[:157] + "...")


def write_index(out: Path, docs) -> None:
    """`out`/index.html, the page a user opens: each module with its summary, then the first module's public names
    (for `engine`, its `__all__`) with theirs, linked to their pages. pdoc's own index.html only redirects to
    engine.html, whose page does not link the other modules (they are not in `engine.__all__`)."""
    import engine

    mods = "\n".join(
        f'<li><a href="{d.fullname.replace(".", "/")}.html"><code>{d.fullname}</code></a> - '
        f"{_summary(d.docstring)}</li>"
        for d in docs
    )
    names = "\n".join(
        f'<li><a href="{docs[0].fullname.replace(".", "/")}.html#{m.name}"><code>{m.name}</code></a>'
        f" - {_summary(m.docstring)}</li>"
        for m in docs[0].members.values()
        if not m.name.startswith("_")
    )
    title = f"hybrid {engine.__version__}: API reference"
    (out / "index.html").write_text(f"""<!doctype html>
<html lang="en">
<head><meta charset="utf-8"><title>{title}</title>
<style>body {{ font-family: sans-serif; max-width: 60em; margin: 2em auto; line-height: 1.5 }}
li {{ margin: 0.2em 0 }}</style></head>
<body>
<h1>{title}</h1>
<p>Built from the docstrings by <code>tools/build_api_docs.py</code> (<code>./hybrid docs</code>). Guides:
README.md and docs/ in the repository.</p>
<h2>Modules</h2>
<ul>
{mods}
</ul>
<h2>{docs[0].fullname}</h2>
<ul>
{names}
</ul>
</body>
</html>
""")


def build(out: Path | None) -> list[str]:
    """Render the reference into `out` (None: a temporary folder, discarded); the problems found, as lines."""
    import pdoc
    import pdoc.doc
    import pdoc.doc_types
    import pdoc.render

    pdoc.render.configure(docformat=DOCFORMAT, show_source=False, search=True)
    _short_numpy_aliases(pdoc.doc, pdoc.doc_types)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) if out is None else out
            pdoc.pdoc(*MODULES, output_directory=folder)
            docs = [pdoc.doc.Module.from_name(name) for name in MODULES]
            write_index(folder, docs)
    problems = [f"pdoc: {w.category.__name__}: {w.message}" for w in caught]
    return problems + check_docstrings(docs)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=REPO / "docs" / "api", help="folder to write (docs/api)")
    ap.add_argument("--check", action="store_true", help="only check: write nothing")
    args = ap.parse_args(argv)
    problems = build(None if args.check else args.output)
    for line in problems:
        print(f"error: {line}", file=sys.stderr)
    if problems:
        return 1
    if not args.check:
        print(
            f"{args.output / 'index.html'}: the API reference of {', '.join(MODULES)} "
            f"({len(list(args.output.rglob('*.html')))} pages); open it in a browser"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
