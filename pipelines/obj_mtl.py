"""OBJ materials: finding referenced files inside the model's folder, parsing MTL files and
mapping their statements to :class:`pipelines.model.Material` (see :func:`_build_material`).
Used by :mod:`pipelines.import_obj`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assetpipe.core.errors import AssetError
from assetpipe.pipelines.image_source import read_image_file, resolve_inside
from assetpipe.pipelines.model import CLAMP_TO_EDGE, ImageSource, Material, Sampler, TextureRef
from assetpipe.pipelines.obj_text import decode_text, read_normalised

# Files searched at most when looking a texture up by name under the model's folder.
_MAX_INDEXED_FILES = 50_000
# Options of MTL map statements and how many arguments they take (max; -o/-s/-t take 1..3).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1,
                "-colorspace": 1}
_NUMERIC_OPTIONS = frozenset({"-bm", "-boost", "-mm", "-o", "-s", "-t", "-texres"})
_FLOAT_RE = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


# --------------------------------------------------------------------------------------
# Finding files inside the model's folder


class Finder:
    """Looks referenced files (MTL, textures) up inside the model's folder only."""

    def __init__(self, root: Path):
        self.root = root.resolve()
        self._index: dict[str, list[Path]] | None = None
        self._index_lower: dict[str, list[Path]] | None = None

    def _build_index(self) -> None:
        exact: dict[str, list[Path]] = {}
        lower: dict[str, list[Path]] = {}
        count = 0
        for dirpath, dirnames, filenames in os.walk(self.root):  # does not follow symlinked dirs
            dirnames.sort()
            for fname in sorted(filenames):
                p = Path(dirpath) / fname
                exact.setdefault(fname, []).append(p)
                lower.setdefault(fname.lower(), []).append(p)
                count += 1
            if count > _MAX_INDEXED_FILES:
                break
        key = lambda p: (len(p.parts), str(p))  # noqa: E731 - shallowest first, then by name
        self._index = {k: sorted(v, key=key) for k, v in exact.items()}
        self._index_lower = {k: sorted(v, key=key) for k, v in lower.items()}

    def find(self, written: str, rel_dirs: list[Path], referrer: Path, what: str) -> tuple[Path | None, str | None]:
        """Resolve a path as written in ``referrer``.

        Returns (the file, or None; a warning or None).
        """
        cleaned = written.strip().strip('"').replace("\\", "/")
        absolute = cleaned.startswith("/") or re.match(r"^[A-Za-z]:", cleaned) is not None
        escaped = False
        if cleaned and not absolute:
            for d in rel_dirs:
                rel = os.path.join(os.path.relpath(d, self.root), cleaned)
                try:
                    target = resolve_inside(self.root, rel, referrer)
                except AssetError:
                    escaped = True
                    continue
                if target.is_file():
                    return target, None
        name = cleaned.rstrip("/").rsplit("/", 1)[-1]
        found = self._by_name(name, referrer) if name not in ("", ".", "..") else None
        if found is not None:
            if escaped:
                return found, (f"{referrer.name}: {what} {written!r} points outside the model's folder; "
                               f"using {os.path.relpath(found, self.root)!r} found inside it")
            return found, None
        if escaped:
            return None, f"{referrer.name}: {what} {written!r} is outside the model's folder: not read"
        return None, f"{referrer.name}: {what} {written!r} not found"

    def _by_name(self, name: str, referrer: Path) -> Path | None:
        if self._index is None:
            self._build_index()
        assert self._index is not None and self._index_lower is not None
        for candidates in (self._index.get(name, []), self._index_lower.get(name.lower(), [])):
            for p in candidates:
                try:
                    target = resolve_inside(self.root, os.path.relpath(p, self.root), referrer)
                except AssetError:
                    continue  # a symlink leading out of the folder
                if target.is_file():
                    return target
        return None


# --------------------------------------------------------------------------------------
# MTL


@dataclass
class _MapRef:
    """A map statement: the file name as written and its options."""

    file: str
    clamp: bool = False
    transformed: bool = False  # -o / -s with non-default values


def _parse_map(rest: str) -> _MapRef | None:
    """Parse the arguments of a ``map_*`` / ``bump`` / ``norm`` statement (options, then file).

    The file name is the rest of the line after the options, spaces included.
    """
    spans = [(m.group(), m.start()) for m in re.finditer(r"\S+", rest)]
    i, clamp, transformed = 0, False, False
    while i < len(spans) - 1 and spans[i][0].startswith("-") and not _FLOAT_RE.match(spans[i][0]):
        opt = spans[i][0].lower()
        i += 1
        args: list[str] = []
        limit = _MAP_OPTIONS.get(opt, 3)
        numeric = opt in _NUMERIC_OPTIONS or opt not in _MAP_OPTIONS
        while len(args) < limit and i < len(spans) - 1:
            tok = spans[i][0]
            if numeric and not _FLOAT_RE.match(tok):
                break
            args.append(tok)
            i += 1
            if not numeric:
                break
        if opt == "-clamp" and args and args[0].lower() == "on":
            clamp = True
        if opt in ("-o", "-s"):
            default = 0.0 if opt == "-o" else 1.0
            if any(float(a) != default for a in args):
                transformed = True
    if i >= len(spans):
        return None
    return _MapRef(rest[spans[i][1]:].strip(), clamp, transformed)


def _floats(rest: str, count: int) -> tuple[float, ...] | None:
    try:
        vals = tuple(float(t) for t in rest.split()[:count])
    except ValueError:
        return None
    if len(vals) == 1 and count == 3:
        vals = vals * 3  # "Kd 0.5" means grey
    if len(vals) != count or not all(np.isfinite(vals)):
        return None
    return vals


def _parse_mtl(data: bytes, mtl_path: Path, warnings: list[str]) -> list[tuple[str, dict[str, object]]]:
    """The materials of an MTL file: [(name, {statement: parsed value})] in file order."""
    materials: list[tuple[str, dict[str, object]]] = []
    current: dict[str, object] | None = None
    for lineno, raw_line in enumerate(data.split(b"\n"), 1):
        text = decode_text(raw_line).strip()
        if not text or text.startswith("#"):
            continue
        keyword, _, rest = text.partition(" ")
        keyword, rest = keyword.lower(), rest.strip()
        if keyword == "newmtl":
            current = {}
            materials.append((rest or "unnamed", current))
            continue
        if current is None:
            continue
        if keyword in ("kd", "ke"):
            vals = _floats(rest, 3)
            if vals is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: cannot read {keyword.capitalize()} {rest!r}")
            else:
                current[keyword] = vals
        elif keyword in ("d", "tr", "pm", "pr"):
            tokens = [t for t in rest.split() if t != "-halo"]
            vals = _floats(tokens[0] if tokens else "", 1)
            if vals is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: cannot read {keyword} {rest!r}")
            else:
                current[keyword] = vals[0]
        elif keyword in ("map_kd", "map_d", "map_bump", "bump", "norm", "map_ke", "map_kn"):
            ref = _parse_map(rest)
            if ref is None:
                warnings.append(f"{mtl_path.name}: line {lineno}: {keyword} without a file name")
            else:
                role = {"map_bump": "bump", "norm": "bump", "map_kn": "bump"}.get(keyword, keyword)
                current.setdefault(role, ref)
    return materials


@dataclass
class ObjContext:
    """What an import accumulates: warnings, files read, images by path."""

    path: Path
    finder: Finder
    warnings: list[str] = field(default_factory=list)
    dependencies: list[Path] = field(default_factory=list)
    images: dict[Path, ImageSource] = field(default_factory=dict)

    def read_dep(self, p: Path) -> None:
        if p not in self.dependencies:
            self.dependencies.append(p)

    def texture(self, ref: _MapRef, mtl_path: Path, what: str) -> TextureRef | None:
        found, warning = self.finder.find(ref.file, [mtl_path.parent, self.path.parent], mtl_path, what)
        if warning:
            self.warnings.append(warning)
        if found is None:
            return None
        image = self.images.get(found)
        if image is None:
            image = read_image_file(found, mtl_path, name=found.name)
            self.images[found] = image
            self.read_dep(found)
        if ref.transformed:
            self.warnings.append(f"{mtl_path.name}: texture options -o/-s on {ref.file!r} are not supported: ignored")
        sampler = Sampler(wrap_s=CLAMP_TO_EDGE, wrap_t=CLAMP_TO_EDGE) if ref.clamp else Sampler()
        return TextureRef(image=image, sampler=sampler)


def _build_material(name: str, st: dict[str, object], mtl_path: Path, ctx: ObjContext) -> Material:
    """One glTF-style material from MTL statements.

    * ``Kd`` -> base colour RGB (white if absent). A ``Kd 0 0 0`` next to a ``map_Kd`` would
      render the texture black (an exporter habit), so it becomes white, with a warning.
    * ``d`` -> alpha; without ``d``, ``Tr`` -> alpha = 1 - Tr. ``Tr 1`` alone (alpha 0, an
      invisible material) is what MeshLab and others write for *opaque*: read as alpha 1,
      with a warning. alpha < 1 -> alphaMode BLEND.
    * ``map_Kd`` -> base colour texture; ``map_Bump`` / ``bump`` / ``norm`` -> normal
      texture; ``Ke`` / ``map_Ke`` -> emissive; ``Pm`` / ``Pr`` -> metallic / roughness
      (metallic is 0 otherwise: OBJ materials are not metals).
    * ``map_d``: the model has no separate alpha texture. When it names the same image as
      ``map_Kd`` the texture's own alpha is meant: alphaMode BLEND. Otherwise it is ignored
      (never used as the base colour, since it is a grey mask) with a warning.
    """
    kd = st.get("kd", (1.0, 1.0, 1.0))
    assert isinstance(kd, tuple)
    alpha = 1.0
    if "d" in st:
        alpha = float(st["d"])  # type: ignore[arg-type]
    elif "tr" in st:
        alpha = 1.0 - float(st["tr"])  # type: ignore[arg-type]
        if alpha <= 0.0:
            ctx.warnings.append(f"{mtl_path.name}: material {name!r} has Tr {st['tr']} (fully transparent); "
                                "read as opaque, as the exporter most likely meant")
            alpha = 1.0
    alpha = min(max(alpha, 0.0), 1.0)
    alpha_mode = "BLEND" if alpha < 1.0 else "OPAQUE"

    base_tex = normal_tex = emissive_tex = None
    kd_ref = st.get("map_kd")
    if isinstance(kd_ref, _MapRef):
        base_tex = ctx.texture(kd_ref, mtl_path, "texture")
        if base_tex is not None and tuple(kd) == (0.0, 0.0, 0.0):
            ctx.warnings.append(f"{mtl_path.name}: material {name!r} has Kd 0 0 0 with a texture: "
                                "using white so the texture shows")
            kd = (1.0, 1.0, 1.0)
    d_ref = st.get("map_d")
    if isinstance(d_ref, _MapRef):
        same = isinstance(kd_ref, _MapRef) and base_tex is not None and \
            ctx.finder.find(d_ref.file, [mtl_path.parent, ctx.path.parent], mtl_path, "alpha texture")[0] \
            == Path(base_tex.image.origin)
        if same:
            alpha_mode = "BLEND"
        else:
            ctx.warnings.append(f"{mtl_path.name}: material {name!r}: separate alpha map {d_ref.file!r} "
                                "(map_d) is not supported: ignored")
    bump_ref = st.get("bump")
    if isinstance(bump_ref, _MapRef):
        normal_tex = ctx.texture(bump_ref, mtl_path, "normal texture")
    ke_ref = st.get("map_ke")
    if isinstance(ke_ref, _MapRef):
        emissive_tex = ctx.texture(ke_ref, mtl_path, "emissive texture")
    ke = st.get("ke", (1.0, 1.0, 1.0) if emissive_tex is not None else (0.0, 0.0, 0.0))
    assert isinstance(ke, tuple)
    return Material(
        name=name,
        base_color_factor=(float(kd[0]), float(kd[1]), float(kd[2]), alpha),
        base_color_texture=base_tex,
        alpha_mode=alpha_mode,
        metallic_factor=float(st.get("pm", 0.0)),  # type: ignore[arg-type]
        roughness_factor=float(st.get("pr", 1.0)),  # type: ignore[arg-type]
        normal_texture=normal_tex,
        emissive_texture=emissive_tex,
        emissive_factor=(float(ke[0]), float(ke[1]), float(ke[2])),
    )


def _split_mtllib(rest: str, finder: Finder, ctx: ObjContext) -> list[str]:
    """The file names of an ``mtllib`` statement: several names, each possibly with spaces.

    The whole argument is one name if such a file exists; otherwise the words are grouped
    into names ending in ``.mtl``.
    """
    whole, _ = finder.find(rest, [ctx.path.parent], ctx.path, "material library")
    if whole is not None or " " not in rest:
        return [rest]
    names, current = [], []
    for word in rest.split():
        current.append(word)
        if word.lower().endswith(".mtl"):
            names.append(" ".join(current))
            current = []
    if current:
        names.append(" ".join(current))
    return names


def load_materials(mtllibs: list[tuple[int, str]], ctx: ObjContext) -> tuple[list[Material], dict[str, int]]:
    materials: list[Material] = []
    index: dict[str, int] = {}
    seen: set[Path] = set()
    for _, rest in mtllibs:
        for name in _split_mtllib(rest, ctx.finder, ctx):
            found, warning = ctx.finder.find(name, [ctx.path.parent], ctx.path, "material library")
            if found is None:
                ctx.warnings.append((warning or f"material library {name!r} not found") +
                                    ": its materials use the default material")
                continue
            if found in seen:
                continue
            seen.add(found)
            if warning:
                ctx.warnings.append(warning)
            data = read_normalised(found, "MTL", ctx.warnings)
            ctx.read_dep(found)
            for mat_name, statements in _parse_mtl(data, found, ctx.warnings):
                if mat_name in index:
                    ctx.warnings.append(f"{found.name}: material {mat_name!r} defined again: the first one is used")
                    continue
                index[mat_name] = len(materials)
                materials.append(_build_material(mat_name, statements, found, ctx))
    return materials, index


