"""Mesh and glTF files through trimesh, as meshes in object space and the instances that place them
(SceneBuilder -> SceneParts); texture images through pillow."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import warnings

import numpy as np
from PIL import Image

from engine.limits import MAX_COORD
from engine.errors import SceneError, shown

from . import mtl, points
from .classes import extras_class
from .gltf_specular import ATTRIBUTE as SPECULAR_ATTRIBUTE
from .gltf_specular import attach_specular
from .gltf_transmission import IOR_ATTRIBUTE, TRANSMISSION_ATTRIBUTE, attach_transmission
from .filechecks import bomb_images, bomb_pixels, check_mesh_file, diagnose_gltf
from .instances import Mesh, check_transforms, determinants, instance_label, world_boxes
from .material import TEXTURE_FIELDS, Material, material_key, srgb8_to_linear, texture_key
from .parts import Placements, SceneParts

MAX_TEXTURE_SIZE = 2048
#: Most pixels a texture image may have (64 Mpixel, e.g. 8192 x 8192): checked from the image's header, before it is
#: decoded (RGBA at this size is 256 MB; it is downsized to MAX_TEXTURE_SIZE on a side after decoding).
MAX_TEXTURE_PIXELS = 64 * 1024 * 1024
MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".gltf", ".glb", ".off")
USD_EXTENSIONS = (".usd", ".usda", ".usdc", ".usdz")  # stages: usd/ reads them (Scene.load picks it by suffix)
DEFAULT_COLOR = (0.8, 0.8, 0.8, 1.0)
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tga", ".tif", ".tiff", ".gif", ".webp")

log = logging.getLogger(__name__)


@contextlib.contextmanager
def _quiet():
    """trimesh logs (and warns) about files it half-understands; our errors say it instead."""
    logger = logging.getLogger("trimesh")
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with np.errstate(all="ignore"):
                yield
    finally:
        logger.setLevel(level)


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    text = shown(text[0] if text else "", limit=160)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _too_large(pixels: int | None, size=None) -> str:
    """The message for an image over MAX_TEXTURE_PIXELS; `pixels` None: pillow refused it before we could count."""
    limit = f"the limit of {MAX_TEXTURE_PIXELS:,} ({MAX_TEXTURE_PIXELS // 2**20} Mpixel)"
    if pixels is None:
        return f"texture image is too large (pillow refuses it as a decompression bomb; {limit})"
    dims = f" ({size[0]} x {size[1]})" if size else ""
    return f"texture image is too large: {pixels:,} pixels{dims}, more than {limit}"


def check_image_size(img, where: str) -> None:
    """Refuse an opened (not yet decoded) image with more than MAX_TEXTURE_PIXELS pixels."""
    w, h = img.size
    if w * h > MAX_TEXTURE_PIXELS:
        raise SceneError(f"{where}: {_too_large(w * h, (w, h))}")


#: Modes resampled as they are (the same values as resampling their RGBA conversion), then converted to RGBA
_RESAMPLED_AS_IS = ("L", "LA", "RGB", "RGBA")
#: Modes of more than 8 bits a channel: scaled to 8-bit grey (their maximum, or 255, is white)
_WIDE_MODES = ("I;16", "I;16B", "I;16L", "I", "F")
_BLOCK_PIXELS = 1 << 18  # the 16- and 32-bit conversion's float temporaries: this many pixels at a time (2 MB)


def image_to_texture(img, where: str, owned: bool = False) -> np.ndarray:
    """A PIL image to (H, W, 4) uint8 RGBA, at most MAX_TEXTURE_SIZE on a side; at most MAX_TEXTURE_PIXELS before
    it is downsized. `where` names what refers to it in messages; `owned`: the caller's image may be downsized in
    place (no copy).

    Memory is bounded by the decoded image's (1 to 4 bytes a pixel, 16 for 32-bit RGBA float): a grey, RGB or RGBA
    image is downsized in its own mode and only then made RGBA; 16- and 32-bit images are scaled to 8 bits in
    blocks, without a float copy of the whole image (issue #36: a 60 Mpixel 16-bit PNG took 1.9 GB)."""
    try:
        check_image_size(img, where)
        img.load()
        if img.mode in _WIDE_MODES:
            img, owned = _wide_to_grey(img), True
        elif img.mode not in _RESAMPLED_AS_IS:  # palette, 1-bit, CMYK ...: RGBA first (a palette resamples nearest)
            img, owned = img.convert("RGBA"), True
        if max(img.size) > MAX_TEXTURE_SIZE:
            if not owned:
                img = img.copy()
            img.thumbnail((MAX_TEXTURE_SIZE, MAX_TEXTURE_SIZE), Image.Resampling.LANCZOS)
        if img.mode != "RGBA":
            img = img.convert("RGBA")
        tex = np.array(img, dtype=np.uint8)
    except SceneError:
        raise
    except Image.DecompressionBombError as exc:
        raise SceneError(f"{where}: {_too_large(bomb_pixels(exc))}") from None
    except Exception as exc:
        raise SceneError(f"{where}: cannot read texture image ({_short(exc)})") from None
    if tex.ndim != 3 or tex.shape[2] != 4 or tex.shape[0] == 0 or tex.shape[1] == 0:
        raise SceneError(f"{where}: texture image has an unusable shape {tex.shape}")
    return tex


def _wide_to_grey(img):
    """A 16- or 32-bit single-channel image as 8-bit grey: value / max(its maximum, 255) * 255, truncated (float64
    arithmetic on a tile of about _BLOCK_PIXELS pixels at a time: no copy of the whole image besides the result)."""
    w, h = img.size
    top = float(img.getextrema()[1]) if w * h else 0.0
    top = top if top > 255 else 255.0
    out = np.empty((h, w), np.uint8)
    cols = min(w, _BLOCK_PIXELS)
    rows = max(1, _BLOCK_PIXELS // cols)
    for y in range(0, h, rows):
        for x in range(0, w, cols):
            tile = np.asarray(img.crop((x, y, min(x + cols, w), min(y + rows, h))), dtype=np.float64)
            out[y : y + rows, x : x + cols] = np.clip(tile / top * 255.0, 0, 255)
    return Image.fromarray(out, "L")


def load_texture_file(path: str, where: str) -> np.ndarray:
    """An image file to a texture; `where` names what refers to it (e.g. 'scene.toml: [[mesh]] #2: texture')."""
    if os.path.exists(path) and not os.path.isfile(path):
        raise SceneError(f"{where}: texture is not a regular file: {shown(path)}")
    if not os.path.isfile(path):
        raise SceneError(f"{where}: texture file not found: {shown(path)}")
    try:
        with warnings.catch_warnings():  # PIL warns of a large image; image_to_texture says more
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)  # reads the header only: its size is checked before decoding
        with img:
            return image_to_texture(img, f"{where} ({shown(path)})", owned=True)
    except SceneError:
        raise
    except Image.DecompressionBombError as exc:
        raise SceneError(f"{where} ({shown(path)}): {_too_large(bomb_pixels(exc))}") from None
    except Exception as exc:
        raise SceneError(f"{where}: cannot read texture image {shown(path)} ({_short(exc)})") from None


def _resolver(path: str):
    """A trimesh resolver for the files a mesh file refers to (MTL, textures, glTF buffers) that refuses
    non-regular files (a FIFO would block the read) and notes in `.problems` what was missing or unreadable."""
    from trimesh.resolvers import FilePathResolver  # deferred: heavy, and needed only to read meshes

    class Resolver(FilePathResolver):
        def __init__(self, source):
            super().__init__(source)
            self.problems = []

        def get(self, name: str):
            name = name.strip()
            ext = os.path.splitext(name)[1].lower()
            what = "material file" if ext == ".mtl" else "texture" if ext in IMAGE_EXTENSIONS else "referenced file"
            for candidate in (name, name.lstrip("/"), os.path.split(name)[-1]):
                try:
                    full = self.absolute(candidate)
                except ValueError:
                    continue
                if full.exists():
                    if not full.is_file():
                        self.problems.append(f"{what} {name!r} is not a regular file")
                        raise OSError(f"{name}: not a regular file")
                    data = full.read_bytes()
                    if what == "texture":
                        _check_image(data, name, self.problems)
                    return data
            where = "not found next to the mesh file"
            if ".." in name.replace("\\", "/").split("/"):
                where = "outside the mesh file's folder, which is not searched"
            self.problems.append(f"{what} {name!r} {where}")
            raise FileNotFoundError(name)

    return Resolver(path)


def _check_image(data: bytes, name: str, problems: list) -> None:
    """Note an image trimesh will fail to open (it drops it without a word); refuse one that is too large (an
    OSError: trimesh drops it too)."""
    try:
        with Image.open(io.BytesIO(data)) as img:
            pixels = img.size[0] * img.size[1]
            size = img.size
    except Image.DecompressionBombError as exc:
        pixels, size = bomb_pixels(exc), None
    except Exception:
        problems.append(f"texture {name!r} is unreadable (not an image file pillow can read)")
        return
    if pixels is None or pixels > MAX_TEXTURE_PIXELS:
        problems.append(f"texture {name!r}: {_too_large(pixels, size)}")
        raise OSError(f"{name}: too large")


def load_trimesh_scene(path: str, *, scene_file: bool = False):
    """trimesh.load_scene with our errors: missing file, unsupported type, unreadable or corrupt content.

    `scene_file`: the path was given as a scene (a .toml would have been one too), not as a [[mesh]] file.
    Referenced files (textures, MTL) that are missing or unreadable are logged as warnings; the mesh is kept.
    """
    import trimesh  # deferred: heavy, and needed only to read meshes

    where = shown(path)
    if not os.path.exists(path):
        raise SceneError(f"{where}: file not found")
    if os.path.isdir(path):
        raise SceneError(f"{where}: is a directory, not a scene file")
    if not os.path.isfile(path):  # a FIFO or a device would block the read or never end
        raise SceneError(f"{where}: not a regular file")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".toml" and not scene_file:
        raise SceneError(
            f"{where}: a .toml scene cannot be used as a mesh file (mesh files: {', '.join(MESH_EXTENSIONS)})"
        )
    if ext not in MESH_EXTENSIONS:
        supported = ", ".join(
            ((".toml",) if scene_file else ()) + MESH_EXTENSIONS + (USD_EXTENSIONS if scene_file else ())
        )
        raise SceneError(f"{where}: unsupported file type '{shown(ext) or '(none)'}' (supported: {supported})")
    try:
        if os.path.getsize(path) == 0:
            raise SceneError(f"{where}: file is empty")
        problem = check_mesh_file(path, ext)  # what trimesh would accept silently (OBJ index 0)
        if problem:
            raise SceneError(f"{where}: {problem}")
        resolver = _resolver(path)
        with _quiet():
            # process=False: keep the file's vertices as they are (trimesh would silently drop NaN vertices and
            # weld STL corners); we validate, and compute missing normals with creases ourselves
            obj = trimesh.load_scene(path, process=False, resolver=resolver)
            if ext == ".obj":
                mtl.load_images(obj, resolver, where)
        problems = list(resolver.problems)
        if ext in (".gltf", ".glb"):  # images pillow refused inside the file, which trimesh drops quietly
            problems += [f"images[{i}]: {_too_large(pixels)}" for i, pixels in bomb_images(path)]
            attach_specular(obj, path, where)
            attach_transmission(obj, path, where)
        for problem in dict.fromkeys(problems):
            log.warning(f"{where}: {problem}; rendering without it")
        return obj
    except SceneError:
        raise
    except MemoryError:
        raise SceneError(f"{where}: corrupt {ext} file (asks for more memory than there is)") from None
    except RecursionError:
        raise SceneError(f"{where}: corrupt {ext} file (nested too deeply)") from None
    except Image.DecompressionBombError as exc:  # an image inside the file (GLB)
        raise SceneError(f"{where}: {_too_large(bomb_pixels(exc))}") from None
    except Exception as exc:
        # trimesh's own exception says little about a glTF it cannot follow: say what is wrong with it
        why = diagnose_gltf(path) if ext in (".gltf", ".glb") else None
        if why:
            raise SceneError(f"{where}: {why}") from None
        raise SceneError(
            f"{where}: cannot read {ext} file, it is corrupt or not a valid {ext[1:].upper()} file ({_short(exc)})"
        ) from None


class SceneBuilder:
    """Collects meshes (object space; a geometry used several times is one Mesh) and the instances that place
    them, and materials, then hands them over as SceneParts."""

    def __init__(self, name: str):
        self.name = name
        self.meshes: list[Mesh] = []
        # the instances, in blocks: mesh indices (K,), transforms (K, 4, 4), and names (one list)
        self._inst_mesh: list[np.ndarray] = []
        self._inst_transforms: list[np.ndarray] = []
        self._inst_names: list[str] = []
        self._inst_classes: list[str | None] = []
        self.materials: list[Material] = []
        self._material_keys: dict = {}
        self._textures: dict = {}
        self._mesh_keys: dict = {}
        self._keep: list = []  # the objects whose ids are in _mesh_keys, kept alive so the ids stay unique
        self._point_radius = None  # add_trimesh's, for its point clouds
        self.point_pixels = None  # point clouds' splats this many pixels wide (None: world-sized)

    # -------------------------------------------------------------- materials
    def material_index(self, mat: Material, key_name=None) -> int:
        """Index of `mat` in the scene: a material already added with the same name, factors and texture pixels
        is reused, and equal texture images are shared. `key_name` (any hashable) stands for the name in that
        comparison (e.g. the file's material name for a material renamed after its node)."""
        shared = {}
        for field in TEXTURE_FIELDS:
            tex = getattr(mat, field)
            if tex is not None:
                kept = self._textures.setdefault(texture_key(tex), tex)
                if kept is not tex:
                    shared[field] = kept
        if shared:
            mat = mat.with_overrides(**shared)
        key = material_key(mat, key_name)
        if key not in self._material_keys:
            self._material_keys[key] = len(self.materials)
            self.materials.append(mat)
        return self._material_keys[key]

    # -------------------------------------------------------------- geometry
    def add(
        self,
        name: str,
        positions,
        faces,
        normals,
        uvs,
        material: int,
        where: str,
        transform=None,
        key=None,
        instance_name: str | None = None,
        cls: str | None = None,
    ):
        """Add a part in object space placed by `transform` ((4, 4); None: identity). Parts added with the same
        hashable `key` (not None) share the first one's Mesh. `normals` None: computed with a crease angle."""
        m = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64)
        inst_name = name if instance_name is None else instance_name
        self.add_placed(
            name, positions, faces, normals, uvs, material, where, m[None], [inst_name], key=key, classes=[cls]
        )

    def add_placed(
        self, name, positions, faces, normals, uvs, material, where, transforms, names, key=None, classes=None
    ):
        """`add` for K placements at once: `transforms` (K, 4, 4), `names` K instance names, `classes` K semantic
        classes (or None: none); checked with whole-array
        operations (the first bad placement is named, with the message `add` gives). Placements whose 3x3 part is
        singular (a zero scale: glTF hides parts so) are left out."""
        m = np.asarray(transforms, dtype=np.float64)
        finite = np.isfinite(m.reshape(len(m), 16)).all(axis=1)
        if not finite.all():
            j = int(np.argmin(finite))
            raise SceneError(f"{where}: node '{shown(names[j])}' has a transform with NaN or infinite values")
        k = self._mesh_keys.get(key) if key is not None else None
        if k is None:
            mesh = self._mesh(name, positions, faces, normals, uvs, material, where)
            if mesh is None:
                return
            k = len(self.meshes)
            self.meshes.append(mesh)
            if key is not None:
                self._mesh_keys[key] = k
        a = m[:, :3, :3]
        top = np.maximum(np.abs(a).reshape(len(m), 9).max(axis=1), 1e-300)
        shown_ = np.abs(determinants(m / top[:, None, None])) >= 1e-12  # (a finite det >= 1e-12: a finite cond)
        classes = [None] * len(m) if classes is None else list(classes)
        if not shown_.all():  # a zero scale hides the part: nothing to trace or draw
            m = m[shown_]
            names = [n for n, keep in zip(names, shown_) if keep]
            classes = [c for c, keep in zip(classes, shown_) if keep]
            if not len(m):
                return
        box = np.abs(world_boxes(self.meshes[k].box[None], m)).reshape(len(m), 6).max(axis=1)
        if box.max() > MAX_COORD:
            j = int(np.argmax(box > MAX_COORD))
            raise SceneError(
                f"{where}: mesh '{shown(names[j])}' has world-space vertex coordinates beyond "
                f"+-{MAX_COORD:g} (largest {box[j]:g}): check its size, scale and translate"
            )
        m = check_transforms(m, lambda j: instance_label(names[j]), copy=False)  # affine, invertible
        self._inst_mesh.append(np.full(len(m), k, np.int64))
        self._inst_transforms.append(m)
        self._inst_names.extend(names)
        self._inst_classes.extend(classes)

    def _mesh(self, name, positions, faces, normals, uvs, material, where) -> Mesh | None:
        p = np.asarray(positions, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        if p.ndim != 2 or p.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
            raise SceneError(
                f"{where}: mesh '{shown(name)}' has malformed arrays (vertices {p.shape}, faces {f.shape})"
            )
        if len(f) == 0:
            return None
        if not np.all(np.isfinite(p)):
            bad = int(np.count_nonzero(~np.all(np.isfinite(p), axis=1)))
            raise SceneError(f"{where}: mesh '{shown(name)}' has {bad} vertex position(s) that are NaN or infinite")
        if np.abs(p).max() > MAX_COORD:
            raise SceneError(
                f"{where}: mesh '{shown(name)}' has world-space vertex coordinates beyond +-{MAX_COORD:g} "
                f"(already in its own space; largest {np.abs(p).max():g}): check its size"
            )
        if f.min() < 0 or f.max() >= len(p):
            raise SceneError(f"{where}: mesh '{shown(name)}' has face indices out of range")
        if uvs is not None:
            uvs = np.asarray(uvs, dtype=np.float64)
            if uvs.shape != (len(p), 2) or not np.all(np.isfinite(uvs)):
                uvs = None
        if normals is not None:
            normals = np.asarray(normals, dtype=np.float64)
            if (
                normals.shape != (len(p), 3)
                or not np.all(np.isfinite(normals))
                or np.any(np.linalg.norm(normals, axis=1) < 1e-12)
            ):
                normals = None
        return Mesh(
            p,
            f,
            normals=normals,
            uvs=uvs,
            vertex_material=np.full(len(p), material, dtype=np.uint32),
            name=name,
            where=f"{where}: mesh '{shown(name)}'",
        )

    def add_trimesh(
        self,
        obj,
        where: str,
        transform=None,
        color=None,
        texture=None,
        label: str | None = None,
        uv_scale=None,
        overrides: dict | None = None,
        transforms=None,
        labels=None,
        cls: str | None = None,
        classes=None,
        point_radius=None,
    ):
        """Add a trimesh.Trimesh, PointCloud or Scene (node transforms applied, then `transform`); with `transforms`
        (a list of (4, 4)), once per transform (each applied after `transform`), `labels` (None or a name per
        transform) replacing `label` for that placement. A geometry used by several nodes
        (or added again from the same `obj`) stays one mesh with several instances.

        `color` (linear RGBA), `texture` and `overrides` (other Material fields: metallic, roughness, emissive) override
        every material of `obj` (material overrides of the TOML format). Point clouds become splats (points.py) of
        `point_radius` (object-space units; None: their spacing). The semantic class of a placement: its entry of
        `classes`, else `cls`, else the file's (`extras` `class` / `category` of the node or a node above it, else of
        its mesh).
        """
        import trimesh  # deferred: heavy, and needed only to read meshes

        if isinstance(obj, trimesh.PointCloud):
            items = [(np.eye(4), obj, label or "points", "points")]
            file_classes = [extras_class(obj.metadata)]
        elif isinstance(obj, trimesh.Trimesh):
            items = [(np.eye(4), obj, label or getattr(obj.metadata, "get", lambda *_: None)("name") or "mesh", "mesh")]
            file_classes = [extras_class(obj.metadata)]
        elif isinstance(obj, trimesh.Scene):
            items = []
            with _quiet():
                for node in obj.graph.nodes_geometry:
                    m, geom_name = obj.graph[node]
                    geom = obj.geometry.get(geom_name)
                    if isinstance(geom, (trimesh.Trimesh, trimesh.PointCloud)):
                        items.append((np.asarray(m, dtype=np.float64), geom, str(node), str(geom_name)))
            file_classes = [
                _node_class(obj.graph, str(node)) or extras_class(geom.metadata) for _, geom, node, _ in items
            ]
        else:
            raise SceneError(f"{where}: expected a trimesh.Trimesh or trimesh.Scene, got {type(obj).__name__}")
        outer = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64)
        if transforms is None:
            places, names = outer[None], [label]
        else:
            places = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4) @ outer
            names = [(labels[i] if labels and labels[i] else label) for i in range(len(places))]
        given = [(classes[i] if classes and classes[i] else cls) for i in range(len(places))]
        before = len(self._inst_names)
        self._point_radius = point_radius
        made = {}  # this call's materials by trimesh material; `obj` keeps those alive, so their ids stay unique
        self._keep.append(obj)
        in_scene, extra = isinstance(obj, trimesh.Scene), overrides or {}
        if len(items) == 1:  # one geometry, placed once or many times: one block
            m, geom, node_name, geom_name = items[0]
            names = [_node_name(name, node_name, in_scene, 1) for name in names]
            kinds = [c or file_classes[0] for c in given]
            self._add_geometry(geom, places @ m, names, geom_name, where, color, texture, uv_scale, made, extra, kinds)
        else:
            for place, name, c in zip(places, names, given):
                for (m, geom, node_name, geom_name), own in zip(items, file_classes):
                    node_name = _node_name(name, node_name, in_scene, len(items))
                    place_m = (place @ m)[None]
                    self._add_geometry(
                        geom, place_m, [node_name], geom_name, where, color, texture, uv_scale, made, extra, [c or own]
                    )
        if len(self._inst_names) == before:
            raise SceneError(f"{where}: contains no triangles")

    def _add_geometry(self, geom, m, names, geom_name, where, color, texture, uv_scale, made, overrides, classes):
        """One trimesh geometry placed by the transforms `m` (K, 4, 4), its instances named `names`."""
        import trimesh  # deferred: heavy, and needed only to read meshes

        if isinstance(geom, trimesh.PointCloud):
            self._add_points(geom, m, names, geom_name, where, color, overrides, classes)
            return
        node_name = names[0]
        with _quiet():
            vertices = np.asarray(geom.vertices, dtype=np.float64)
            faces = np.asarray(geom.faces, dtype=np.int64)
            normals = None
            if "vertex_normals" in geom._cache.cache:
                try:
                    normals = np.asarray(geom._cache.cache["vertex_normals"], dtype=np.float64)
                except Exception:
                    normals = None
            visual = geom.visual
        if faces.ndim != 2 or len(faces) == 0:
            return
        if not np.all(np.isfinite(vertices)):
            bad = int(np.count_nonzero(~np.all(np.isfinite(vertices), axis=1)))
            raise SceneError(
                f"{where}: mesh '{shown(node_name)}' has {bad} vertex position(s) that are NaN or infinite"
            )
        if not np.all(np.isfinite(m)):
            j = int(np.argmin(np.isfinite(m.reshape(len(m), 16)).all(axis=1)))
            raise SceneError(f"{where}: node '{shown(names[j])}' has a transform with NaN or infinite values")
        uvs = None
        mat = _material_of(visual, where, made)
        uv = getattr(visual, "uv", None) if getattr(visual, "material", None) is not None else None
        if uv is not None:
            uv = np.asarray(uv, dtype=np.float64)
            if uv.shape == (len(vertices), 2) and np.all(np.isfinite(uv)):
                uvs = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])  # trimesh: v up -> image rows top-down
                if uv_scale is not None:
                    uvs = uvs * np.asarray(uv_scale, dtype=np.float64)
        key_name = None
        if color is not None or texture is not None or overrides:
            key_name = mat.name  # overridden the same way, one material of the file stays one
            mat = mat.with_overrides(color, texture, name=node_name if color is not None else mat.name, **overrides)
        material = self.material_index(mat, key_name)
        key = (id(geom), material, None if uv_scale is None else tuple(np.asarray(uv_scale, np.float64).tolist()))
        self._keep.append(geom)
        self.add_placed(geom_name, vertices, faces, normals, uvs, material, where, m, names, key=key, classes=classes)

    def add_points(
        self,
        name,
        positions,
        normals,
        colors,
        radius,
        where,
        transforms,
        names,
        key=None,
        color=None,
        overrides=None,
        classes=None,
    ):
        """A point cloud as splats (points.py) placed by `transforms` (K, 4, 4): `colors` (N, 3|4) uint8 sRGB or
        None, `normals` (N, 3) or None, `radius` a number, (N,) or None (their spacing); `color` (linear RGBA)
        replaces the points' colours, `overrides` other Material fields. With the builder's `point_pixels`, the
        splats are that many pixels wide (Scene.size_points)."""
        what = f"{where}: point cloud '{shown(name)}'"
        colors = None if color is not None else colors
        sp = points.splats(positions, normals, colors, radius, where=what, pixels=self.point_pixels)
        base = color if color is not None else (1.0, 1.0, 1.0, 1.0) if sp.texture is not None else DEFAULT_COLOR
        mat = Material(name, base, sp.texture)
        if overrides:
            mat = mat.with_overrides(**overrides)
        material = self.material_index(mat)
        key = ("points", id(sp)) if key is None else key
        self._keep.append(sp)
        before = len(self.meshes)
        self.add_placed(
            name,
            sp.positions,
            sp.faces,
            sp.normals,
            sp.uvs,
            material,
            where,
            transforms,
            names,
            key=key,
            classes=classes,
        )
        if len(self.meshes) > before:
            self.meshes[-1].splats = sp

    def _add_points(self, geom, m, names, geom_name, where, color, overrides, classes=None):
        """A trimesh.PointCloud (a PLY without faces): its colours and, from a PLY, its normals (nx, ny, nz)."""
        with _quiet():
            vertices = np.asarray(geom.vertices, dtype=np.float64)
            colors = np.asarray(geom.colors) if len(geom.colors) == len(vertices) else None
            raw = (geom.metadata.get("_ply_raw") or {}).get("vertex", {}).get("data", {})
        normals = None
        if isinstance(raw, dict) and all(k in raw for k in ("nx", "ny", "nz")):
            normals = np.column_stack([np.asarray(raw[k], dtype=np.float64).reshape(-1) for k in ("nx", "ny", "nz")])
        colour_key = None if color is None else tuple(np.asarray(color).tolist())
        key = (id(geom), "points", self._point_radius, self.point_pixels, colour_key)
        self._keep.append(geom)
        radius = self._point_radius
        self.add_points(geom_name, vertices, normals, colors, radius, where, m, names, key, color, overrides, classes)

    # -------------------------------------------------------------- result
    def build(self, lights=None, camera=None, settings=None) -> SceneParts:
        """The meshes and instances collected, with the scene's lights, camera and settings."""
        if not self._inst_names:
            raise SceneError(f"{shown(self.name)}: the scene has no triangles")
        placements = Placements(
            np.concatenate(self._inst_mesh),
            np.concatenate(self._inst_transforms),
            self._inst_names,
            self._inst_classes if any(c is not None for c in self._inst_classes) else None,
        )
        return SceneParts(
            name=self.name,
            meshes=self.meshes,
            instances=placements,
            materials=self.materials,
            lights=lights,
            camera=camera,
            settings=settings,
        )


def _node_class(graph, node: str) -> str | None:
    """The class a glTF node's `extras` name, or the nearest node above it that names one (trimesh keeps a node's
    extras as the metadata of the edge from its parent)."""
    parents = graph.transforms.parents
    edges = graph.transforms.edge_data
    seen = set()
    while node in parents and node not in seen:
        seen.add(node)
        parent = parents[node]
        found = extras_class(edges.get((parent, node), {}).get("metadata"))
        if found:
            return found
        node = parent
    return None


def _node_name(name, node_name: str, in_scene: bool, items: int) -> str:
    """The instance name of a file's node placed under `name` (a placement's or the mesh table's, or None)."""
    if name and in_scene:
        return name if items == 1 else f"{name}/{node_name}"
    return name or node_name


def _material_of(visual, where: str, made: dict) -> Material:
    """The Material of a trimesh visual; `made` caches those of trimesh materials (by id: see add_trimesh)."""
    kind = getattr(visual, "kind", None)
    if getattr(visual, "material", None) is not None:
        mat = visual.material
        key = (id(mat), getattr(visual, "uv", None) is None)
        if key not in made:
            made[key] = (mat, _convert_material(mat, visual, where))  # holding `mat` keeps its id from being reused
        return made[key][1]
    if kind in ("face", "vertex"):
        try:
            colors = np.asarray(visual.face_colors if kind == "face" else visual.vertex_colors, dtype=np.float64)
            mean = colors.reshape(-1, 4).mean(axis=0)
        except Exception:
            mean = None
        if mean is not None and np.all(np.isfinite(mean)):
            rgba = np.round(mean).astype(np.uint8)
            return Material("vertex-colors", srgb8_to_linear(rgba))
    return Material("default", DEFAULT_COLOR)


def _convert_material(mat, visual, where: str) -> Material:
    """A trimesh PBRMaterial (glTF) or SimpleMaterial (OBJ/MTL) to a Material; textures of a mesh without UVs and
    images that are too large are left out with a warning."""
    from trimesh.visual.material import PBRMaterial, SimpleMaterial  # deferred: heavy (trimesh)

    name = getattr(mat, "name", None) or "material"
    what = f"{where}: material '{shown(name)}'"
    no_uv = getattr(visual, "uv", None) is None
    warned = []

    def texture(image, field):
        if image is None:
            return None
        if no_uv:
            if not warned:
                log.warning(f"{what} has a texture but the mesh has no UVs; rendering without it")
                warned.append(field)
            return None
        try:
            check_image_size(image, f"{what}: {field}")  # as a referenced file that is too large: without it
        except SceneError as exc:
            log.warning(f"{exc}; rendering without it")
            return None
        return image_to_texture(image, f"{what}: {field}")

    if isinstance(mat, PBRMaterial):
        return _gltf_material(mat, name, texture, what)
    if isinstance(mat, SimpleMaterial):
        return _mtl_material(mat, name, texture)
    return Material(name, DEFAULT_COLOR, texture(getattr(mat, "image", None), "image"))


def _factor(value, default, n=None):
    if value is None:
        return default
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if n is not None and a.shape != (n,):
        return default
    return a if n is not None else float(a[0])


def _gltf_material(mat, name: str, texture, what: str) -> Material:
    """glTF pbrMetallicRoughness, the core material keys and the factors of KHR_materials_specular,
    KHR_materials_transmission and KHR_materials_ior; absent factors take glTF's defaults (metallic 1, roughness 1,
    emissive 0, specular 1, transmission 0, ior 1.5)."""
    factor = mat.baseColorFactor
    base = (1.0, 1.0, 1.0, 1.0) if factor is None else np.asarray(factor, dtype=np.float64) / 255.0
    mode = (mat.alphaMode or "OPAQUE").upper() if isinstance(mat.alphaMode, (str, type(None))) else "OPAQUE"
    specular, specular_color = getattr(mat, SPECULAR_ATTRIBUTE, (1.0, (1.0, 1.0, 1.0)))  # KHR_materials_specular
    try:
        return Material(
            name,
            base,
            texture(mat.baseColorTexture, "baseColorTexture"),
            metallic=float(np.clip(_factor(mat.metallicFactor, 1.0), 0.0, 1.0)),
            roughness=float(np.clip(_factor(mat.roughnessFactor, 1.0), 0.0, 1.0)),
            emissive=np.clip(_factor(mat.emissiveFactor, np.zeros(3), 3), 0.0, None),
            metallic_roughness_texture=texture(mat.metallicRoughnessTexture, "metallicRoughnessTexture"),
            normal_texture=texture(mat.normalTexture, "normalTexture"),
            emissive_texture=texture(mat.emissiveTexture, "emissiveTexture"),
            occlusion_texture=texture(mat.occlusionTexture, "occlusionTexture"),
            alpha_mode=mode if mode in ("OPAQUE", "MASK", "BLEND") else "OPAQUE",
            alpha_cutoff=float(np.clip(_factor(mat.alphaCutoff, 0.5), 0.0, 1.0)),
            double_sided=bool(mat.doubleSided),
            specular=specular,
            specular_color=specular_color,
            transmission=getattr(mat, TRANSMISSION_ATTRIBUTE, 0.0),
            ior=getattr(mat, IOR_ATTRIBUTE, 1.5),
        )
    except SceneError as exc:
        raise SceneError(f"{what}: {exc}") from None


def _mtl_material(mat, name: str, texture) -> Material:
    """OBJ/MTL: Kd -> base colour, map_Kd -> texture, Ks/Ns -> roughness (a dielectric: metallic 0; roughness 1
    without a specular colour), d / Tr -> alpha (BLEND below 1), map_d -> alpha mask (MASK), norm (and a
    map_Bump / bump that is a normal map) -> normal_texture."""
    base = srgb8_to_linear(mat.diffuse) if mat.diffuse is not None else np.array(DEFAULT_COLOR)
    kwargs = getattr(mat, "kwargs", None) or {}
    images = kwargs.get(mtl.IMAGES_KEY, {})
    roughness = 1.0
    specular = kwargs.get("ks")  # as the MTL gave it (trimesh's `specular` has a default colour)
    specular = [specular] if isinstance(specular, (int, float)) else specular
    ns = mtl.number(kwargs.get("ns"), getattr(mat, "glossiness", None))
    if specular is not None and max(mtl.number(x, 0.0) or 0.0 for x in specular) > 0 and ns is not None:
        roughness = mtl.roughness(ns)
    alpha = mtl.number(kwargs.get("d"), None)
    if alpha is None:
        tr = mtl.number(kwargs.get("tr"), None)
        alpha = None if tr is None else 1.0 - tr
    alpha = 1.0 if alpha is None else float(np.clip(alpha, 0.0, 1.0))
    base = np.array(base, dtype=np.float64)
    base[3] = alpha
    mode = "BLEND" if alpha < 1.0 else "OPAQUE"
    tex = texture(mat.image, "map_Kd")
    mask = texture(images.get("map_d"), "map_d")
    if mask is not None:
        tex = mtl.with_alpha(tex, mask)
        mode = "MASK"
    normal, scale = images.get("normal", (None, 1.0))
    return Material(
        name,
        base,
        tex,
        metallic=0.0,
        roughness=roughness,
        normal_texture=texture(normal, "map_Bump"),
        normal_scale=scale,
        alpha_mode=mode,
    )


def load_mesh_file(path: str, transform=None, point_radius=None, point_pixels=None) -> SceneParts:
    """The parts of a scene made of one mesh / glTF file (then `transform`, (4, 4), applied); a point cloud's splats
    of `point_radius` (None: their spacing) or `point_pixels` wide."""
    parts = load_trimesh_scene(path, scene_file=True)
    return trimesh_parts(parts, path, transform=transform, point_radius=point_radius, point_pixels=point_pixels)


def trimesh_parts(
    obj, name: str, lights=None, camera=None, transform=None, point_radius=None, point_pixels=None
) -> SceneParts:
    """The parts of a scene made of a trimesh.Trimesh, PointCloud or Scene (node transforms applied, then
    `transform`)."""
    builder = SceneBuilder(name)
    builder.point_pixels = point_pixels
    builder.add_trimesh(obj, shown(name), transform=transform, point_radius=point_radius)
    return builder.build(lights=lights, camera=camera)
